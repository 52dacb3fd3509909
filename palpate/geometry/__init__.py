"""Shared geometry: the mathematics that several nodes, metrics and tools need, written once.

- ``rotations``: SO(3) and quaternions (w, x, y, z), on ``scipy.spatial.transform.Rotation`` except
  where a scalar fast path serves a per-tick loop.
- ``bezier``: cubic Bezier curves of fingertip trajectories (paper 002, Eqs. 9 and 13-17).

A library layer: it imports numpy, scipy and ``palpate.errors`` only, never the
nodes, the runtime, the launcher or the commands.
"""
