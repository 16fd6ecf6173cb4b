"""The examples in the public API's docstrings run (issue 57, item 5): every module listed has
examples, and every one of them passes."""

import doctest
import importlib

import pytest

MODULES = [
    "metalens_cli.errors",
    "metalens_cli.io.units",
    "metalens_cli.analysis.symmetry",
    "metalens_cli.analysis.bands",
    "metalens_cli.analysis.mtf",
    "metalens_cli.optics.window",
    "metalens_cli.optics.field",
    "metalens_cli.optics.fin",
    "metalens_cli.optics.lens",
    "metalens_cli.optics.split_spectrum",
    "metalens_cli.optics.sampling",
    "metalens_cli.optics.spectra",
    "metalens_cli.imaging.metrics",
]


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples_pass(name):
    module = importlib.import_module(name)
    tests = [test for test in doctest.DocTestFinder().find(module, name) if test.examples]
    assert tests, f"{name} has no docstring examples"
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS)
    for test in tests:
        runner.run(test)
    results = runner.summarize(verbose=False)
    assert results.failed == 0, f"{results.failed} of {results.attempted} examples failed in {name}"
