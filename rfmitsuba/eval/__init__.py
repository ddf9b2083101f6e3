"""Evaluation: SSIM metrics and floors, Stage-1 run evaluation, the dynamic/static protocols, figures."""
