"""Shared geometry: the mathematics that several nodes, metrics and tools need, written once.

- ``rotations``: SO(3) and quaternions (w, x, y, z), on ``scipy.spatial.transform.Rotation`` except
  where a scalar fast path serves a per-tick loop.
- ``bezier``: cubic Bezier curves of fingertip trajectories (paper 002, Eqs. 9 and 13-17).
- ``mesh_query``: queries on a triangle mesh: the one Open3D raycasting set-up (``MeshScene``) and
  the exact closest points, signed distances and sphere touches (``ExactContactSensor``).

A library layer: it imports numpy, scipy, open3d, trimesh and ``palpate.errors`` only, never the
nodes, the runtime, the launcher or the commands.
"""
