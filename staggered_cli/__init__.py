"""staggered: editable staggered poses from dense motion capture (Coleman et al., SCA 2008)."""

__version__ = "0.1.0"
