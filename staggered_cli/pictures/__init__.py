"""Pictures of staggered-pose documents (moved from ``plots.py``; being split by kind)."""
