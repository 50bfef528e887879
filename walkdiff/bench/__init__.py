"""`walkdiff bench ...`: one module per benchmark, each writing its numbers to a file."""
