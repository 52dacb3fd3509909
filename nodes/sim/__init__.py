"""Simulation node: MuJoCo scenes, objects, effectors and exact-mesh contacts."""
