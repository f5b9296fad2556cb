"""Batch studies: stages, executor seam, campaign angles, campaign view."""
