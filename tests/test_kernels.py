"""``make test-cpus`` runs this CPU as other CPUs would (tests/helpers/kernels.py): each of its settings
must really change the kernels that run, or its rerun proves nothing. Each library is asked what it
picked, and each setting's results on fixed inputs are compared with this CPU's own."""

import os

import pytest
from helpers.kernels import SETTINGS, cpu_features, dispatch, moved, probe, runnable


@pytest.mark.cpu_kernels
def test_this_process_runs_the_kernels_its_environment_asks_for():
    """torch's level, the numpy targets left out and OpenBLAS's core are the ones asked for (MKL says
    nothing of its branch: the next test sees it in the numbers)."""
    got = dispatch()
    if "ATEN_CPU_CAPABILITY" in os.environ:
        assert got["torch"] == os.environ["ATEN_CPU_CAPABILITY"].upper()
    disabled = os.environ.get("NPY_DISABLE_CPU_FEATURES", "").replace(",", " ").split()
    assert not set(disabled) & set(got["numpy"]), got["numpy"]
    if "OPENBLAS_CORETYPE" in os.environ:
        assert got["openblas"].lower() == os.environ["OPENBLAS_CORETYPE"].lower()


def test_each_setting_changes_the_numbers_of_each_library_it_moves():
    """Each library a setting moves off this CPU's own kernels computes other numbers on fixed inputs;
    on a CPU with AVX2 (every CPU CI has run on), sse4 moves all four."""
    own = probe(None)
    for name in filter(runnable, SETTINGS):
        other = probe(name)
        libs = moved(own, other)
        if name == "sse4" and cpu_features()["AVX2"]:
            assert libs == {"torch", "numpy", "openblas", "mkl"}, (other["dispatch"], own["dispatch"])
        for lib in libs:
            assert other["fingerprint"][lib] != own["fingerprint"][lib], f"{name}: {lib} computes as before"
