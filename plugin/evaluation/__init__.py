"""Evaluation protocol of SOS-Match (the method spec section 3): footprints, IoU ground truth, claims, metrics."""
