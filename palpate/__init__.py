"""palpate: learning the shape of unknown objects by touch.

The runtime (bus, launcher, recorder, CLI) lives here; the nodes live in `palpate.nodes` and the
message schemas in `palpate.messages`.
"""

__version__ = "0.1.0"
