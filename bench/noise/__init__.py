"""Noise characterisation of a static recording: Allan deviation and its noise terms (IEEE Std 952)."""
