"""Noise node: proprioceptive and contact-sensor noise added to simulated readings."""
