"""Synthetic indoor panoramas with ground truth."""
