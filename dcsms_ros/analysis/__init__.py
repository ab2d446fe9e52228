"""Bag IO, fast CDR codecs, spectral estimators, vibration criteria and reports (no rclpy)."""
