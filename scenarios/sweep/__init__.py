"""Many runs: sweep files, running them in parallel (process pool or Ray), results.csv,
pareto.csv, and ``fleetmap compare``'s statistics and tables."""
