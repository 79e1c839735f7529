"""Operations: pure functions from document (or motion) to document (or motion)."""
