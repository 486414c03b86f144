"""Anchors: volume sampling from Gaussian centres, kNN springs, IDW binding (Eq. 14)."""
