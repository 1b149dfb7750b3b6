"""What pyproject.toml cannot say: the checkout's configs/ folder ships inside the wheel as the package
``cmdp_rl.configs``, where Hydra finds it (``pkg://cmdp_rl.configs``, see cmdp_rl/config/run_config.py). The folder
stays at the root in the checkout, beside cmdp_rl/, where a user looks for it. And the Hydra sweeper of the
hyperparameter search ships as ``hydra_plugins.cmdp_tune``: Hydra finds sweepers only under the ``hydra_plugins``
namespace package, beside (not inside) cmdp_rl."""

from setuptools import find_namespace_packages, find_packages, setup

# Its groups (algo/, env/, ...) are listed as packages too, or setuptools warns that data sits in folders
# that are not packages.
CONFIGS = ["cmdp_rl.configs"] + [f"cmdp_rl.configs.{name}" for name in find_namespace_packages(where="configs")]

setup(
    packages=find_packages(include=["cmdp_rl", "cmdp_rl.*"])
    + CONFIGS
    + find_namespace_packages(include=["hydra_plugins.*"]),
    package_dir={"cmdp_rl.configs": "configs"},
    package_data={name: ["*.yaml"] for name in CONFIGS},
)
