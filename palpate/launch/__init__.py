"""YAML launch files: loading, resolving into a graph, supervising processes."""
