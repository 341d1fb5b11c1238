"""Plans: sweeps over set-ups, targets, Pareto fronts and acceptance planning."""
