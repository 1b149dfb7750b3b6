"""The tabular grid CMDP: env, options, the tabular model and its exact LP optimum."""
