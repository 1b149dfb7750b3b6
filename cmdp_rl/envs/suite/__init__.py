"""The generated suite (``env=suite``): finite-horizon tabular CMDPs drawn from an instance number,
each with its exact constrained optimum (the occupancy LP) and the exact values of any policy table."""
