"""Monte Carlo campaigns: dispersions, per-run seeds, batches on a Dask cluster, budgets."""
