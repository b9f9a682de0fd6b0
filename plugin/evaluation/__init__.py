"""Evaluation protocol of SOS-Match (method.md section 3): footprints, IoU ground truth, claims, metrics."""
