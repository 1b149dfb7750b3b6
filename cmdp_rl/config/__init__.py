"""Configuration: the run's config node and its composition (:mod:`~cmdp_rl.config.run_config`), declared
options and their validation (:mod:`~cmdp_rl.config.validation`), components by name
(:mod:`~cmdp_rl.config.registry`) and torch's thread count (:mod:`~cmdp_rl.config.threads`)."""
