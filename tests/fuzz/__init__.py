"""Helpers of the bad-input suite (tests/test_bad_input.py): mutations of real
motion capture and of real documents, and the checks every bad case passes."""
