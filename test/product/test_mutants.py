"""The curated mutants of ``test/mutation/mutants.py`` stay in step with the code.

``test/mutation/run.py`` reports a mutant whose snippet no longer occurs as ERROR (stale), and a
mutant whose tests moved runs nothing; both pass unnoticed until somebody runs the (slow)
mutation run. These checks are static and fast (no mutant is applied, no pytest is started): every
mutant applies, names tests that exist, and has its own id. Loading is ``run.py``'s own
``load_mutants`` (which also refuses a mutant without a field, a duplicate id, ``old == new``).
"""

import ast
import importlib.util
from functools import lru_cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
RUN = ROOT / 'test' / 'mutation' / 'run.py'


def _load_run():
    spec = importlib.util.spec_from_file_location('zeroshot_mutation_run', RUN)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


RUN_MODULE = _load_run()
MUTANTS = RUN_MODULE.load_mutants()
IDS = [m['id'] for m in MUTANTS]


@lru_cache(maxsize=None)
def _text(path: Path) -> str:
    return path.read_text(encoding='utf-8')


@lru_cache(maxsize=None)
def _test_names(path: Path) -> frozenset:
    """'test_x' and 'TestY::test_x' of the test functions (and methods of Test classes) in a file."""
    names = set()
    for node in ast.parse(_text(path), filename=str(path)).body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.name.startswith('test'):
            names.add(node.name)
        elif isinstance(node, ast.ClassDef) and node.name.startswith('Test'):
            for item in node.body:
                if isinstance(item, (ast.FunctionDef, ast.AsyncFunctionDef)) and item.name.startswith('test'):
                    names.add(f'{node.name}::{item.name}')
    return frozenset(names)


def test_mutant_ids_are_unique():
    duplicates = sorted({i for i in IDS if IDS.count(i) > 1})
    assert not duplicates, f'mutant ids used more than once: {duplicates}'


def test_the_mutant_list_is_not_empty():
    assert len(MUTANTS) > 100


@pytest.mark.parametrize('mutant', MUTANTS, ids=IDS)
def test_every_mutant_applies(mutant):
    path = ROOT / mutant['file']
    assert path.is_file(), f"{mutant['id']}: its file {mutant['file']} does not exist (moved? update 'file')"
    count = _text(path).count(mutant['old'])
    assert count == 1, (f"{mutant['id']}: its old snippet occurs {count} times in {mutant['file']} "
                        f"(must be exactly once): retarget it to where the code now lives")
    assert mutant['new'] != mutant['old'], f"{mutant['id']}: new is the same as old"


@pytest.mark.parametrize('mutant', MUTANTS, ids=IDS)
def test_every_test_a_mutant_names_exists(mutant):
    targets = RUN_MODULE.positional(mutant['tests'])
    assert targets, f"{mutant['id']}: names no test file or node id"
    for target in targets:
        file, _, node = target.partition('::')
        path = ROOT / file
        assert path.is_file(), f"{mutant['id']}: test file {file} does not exist (moved? update 'tests')"
        if node:
            name = node.split('[', 1)[0]
            assert name in _test_names(path), f"{mutant['id']}: {file} has no test {name}"
