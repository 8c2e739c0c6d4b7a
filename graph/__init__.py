"""vislam.graph: the GTSAM factor-graph smoother over the same Sequence, returning an Estimate."""
