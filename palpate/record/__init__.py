"""Message logs: the recorder, the replay node and player, and MCAP helpers (see mcap_io for the format)."""
