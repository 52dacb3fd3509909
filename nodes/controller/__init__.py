"""Controller node: follows cubic Bezier trajectories to touch targets (paper 002, Algorithm 1)."""
