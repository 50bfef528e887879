"""The `walkdiff` command line: one module per command family, `main` only dispatches."""
