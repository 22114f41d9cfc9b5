"""One module per CLI verb: argument parsing and a call into the domain package, nothing else."""
