"""The fork CMDP: three routes to a goal, a randomised optimum (env=fork)."""
