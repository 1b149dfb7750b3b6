"""The scripts behind the first-run figures and the library example read the Makefile and the library guide
(docs/guide/library.md) themselves."""

from cmdp_rl.config.run_config import compose_config
from lab.bench import first_run, library_example


def test_first_run_script_runs_the_makefiles_train_recipe():
    overrides = first_run.make_train_overrides()
    assert overrides == ["algo=ppo_lag", "env=reach1d_torch", "total_steps=3145728"]
    cfg = compose_config(overrides)
    assert cfg.env.backend == "torch" and cfg.env.num_envs == 1024 and cfg.total_steps == 3 * 2**20
    assert cfg.env.optimum(cfg.algo.cost_limit) == __import__("pytest").approx(0.399)


def test_library_example_is_the_readmes_code():
    code = library_example.readme_example()
    assert code.startswith("import cmdp_rl\n") and "cmdp_rl.load_config(" in code and "collector.collect()" in code
    compile(code, "docs/guide/library.md", "exec")
