"""The command line: the click group (``main``), shared options (``options``)
and one thin module per command."""
