"""Planner node: next-best-touch selection with IGEF, GP variance or at random (paper 002, Sec. 2.2-2.4)."""
