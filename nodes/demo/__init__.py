"""The smallest real graph: a clock source that touches a generated cube and a consumer of its contacts."""
