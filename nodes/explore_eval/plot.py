"""A picture of one exploration run: true surface, estimated surface and the contacts."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def plot_formats() -> set[str]:
    """The file suffixes (without the dot) a plot can be saved as."""
    from matplotlib.figure import Figure

    return set(Figure().canvas.get_supported_filetypes())


def plot_run(
    path: Path,
    true_mesh: tuple[np.ndarray, np.ndarray],
    estimate: tuple[np.ndarray, np.ndarray],
    contacts_m: np.ndarray,
    title: str,
    max_faces: int = 4000,
) -> None:
    """Write a PNG: the true mesh (grey, left), the estimate (blue, right), contacts (red) on both."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    fig = plt.figure(figsize=(10, 5))
    panels = (("true surface", true_mesh, "0.7"), ("estimated surface (GPIS)", estimate, "tab:blue"))
    lower, upper = true_mesh[0].min(axis=0), true_mesh[0].max(axis=0)
    centre, half = (lower + upper) / 2, (upper - lower).max() / 2 * 1.1
    for i, (name, (vertices, faces), colour) in enumerate(panels):
        ax = fig.add_subplot(1, 2, i + 1, projection="3d")
        if len(faces):
            step = max(1, len(faces) // max_faces)
            triangles = 1000 * vertices[faces[::step]]
            ax.add_collection3d(Poly3DCollection(triangles, facecolor=colour, edgecolor="none", alpha=0.35))
        if len(contacts_m):
            c = 1000 * contacts_m
            ax.scatter(c[:, 0], c[:, 1], c[:, 2], color="tab:red", s=6)
            ax.plot(c[:, 0], c[:, 1], c[:, 2], color="tab:red", linewidth=0.5, alpha=0.6)
        for setter, k in ((ax.set_xlim, 0), (ax.set_ylim, 1), (ax.set_zlim, 2)):
            setter(1000 * (centre[k] - half), 1000 * (centre[k] + half))
        ax.set_title(name)
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
        ax.set_zlabel("z (mm)")
    fig.suptitle(title)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
