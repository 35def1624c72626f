"""Learned post-processing of first reconstructions (UNet, conditional invertible networks)."""
