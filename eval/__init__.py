"""vislam.eval: data sets, simulation, metrics, consistency, benchmark, plots, command line."""
