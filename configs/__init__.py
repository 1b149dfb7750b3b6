"""The Hydra configs, shipped in the wheel as the package ``cmdp_rl.configs`` (see setup.py): Hydra's
``pkg://`` search path reads only a folder that is a package."""
