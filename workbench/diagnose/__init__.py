"""Residual diagnosis: find what a leg force model lacks, on tunnel campaigns and pool trials (docs/diagnose.md)."""
