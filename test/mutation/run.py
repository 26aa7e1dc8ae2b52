#!/usr/bin/env python3
"""Mutation check: do the tests catch what users rely on?

    .venv/bin/python test/mutation/run.py [--only ID[,ID]] [--list] [--timeout S] [--out FILE]
    make mutation MUTATION_ARGS='--only fov-scale-ignored-in-P'

Applies the curated deliberate bugs of ``test/mutation/mutants.py`` one at a time to a copy of the
repository and runs each one's tests there: a mutant is *killed* when they fail, *SURVIVED* when
they pass (a documented behaviour no test checks), *ERROR* when it cannot be applied (its
snippet no longer occurs exactly once: the list is stale) or its tests select nothing.

The repository is copied once per run to a temporary directory (without .venv, .venv-jazzy-libs,
build, log, .git and caches; with install/, whose node executable the ROS tests start). Each
mutant is applied to the source file and to the same file of the install tree (a plain copy of
the package), its tests run with ``-x`` in the copy, in the ROS environment of the Makefile
pointed at the copy, and the files are restored. The tests of every selected mutant first run
once unmutated: that baseline must pass, else nothing is reported (a failing test would "kill"
every mutant). HOME is a temporary directory, so that no mutant can write into the user's
~/.ros. Python standard library only.

Exit status: 0 every mutant killed, 1 some survived or errored, 2 bad usage or a failing baseline.
"""
from __future__ import annotations

import argparse
import datetime
import filecmp
import importlib.util
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

TOP = Path(__file__).resolve().parents[2]
PKG = 'zeroshot_calib_ros'
EXCLUDED_TOP = {'.venv', '.venv-jazzy-libs', 'build', 'log', '.git'}
"""Top-level entries of the repository that are not copied."""
CACHES = {'__pycache__', '.pytest_cache'}
"""Never copied, at any depth."""
SIBLINGS = ('shared',)
"""Directories beside the repository that tests use (../shared/data): linked beside the copy."""
PYTEST_ARGS = ['-q', '-p', 'no:cacheprovider', '-rfE', '--tb=short']
REQUIRED_KEYS = ('id', 'file', 'old', 'new', 'behaviour', 'tests')
OPTIONS_WITH_VALUE = {'-k', '-m', '-p', '--deselect'}


def positional(tests: list) -> list:
    """The test files / node ids among pytest arguments (options and their values left out)."""
    out, skip = [], False
    for arg in tests:
        if skip:
            skip = False
        elif arg in OPTIONS_WITH_VALUE:
            skip = True
        elif not arg.startswith('-'):
            out.append(arg)
    return out


class Abort(Exception):
    """A condition that stops the run (exit status 2)."""


# --- the mutant list ---------------------------------------------------------------------------

def load_mutants(path: Path = Path(__file__).resolve().parent / 'mutants.py') -> list:
    spec = importlib.util.spec_from_file_location('zeroshot_mutants', path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    mutants = list(module.MUTANTS)
    seen = set()
    for i, m in enumerate(mutants):
        missing = [k for k in REQUIRED_KEYS if k not in m]
        if missing:
            raise Abort(f'{path.name}: mutant {i} ({m.get("id", "?")}) has no {", ".join(missing)}')
        if m['id'] in seen:
            raise Abort(f'{path.name}: mutant id {m["id"]!r} appears twice')
        seen.add(m['id'])
        if m['old'] == m['new']:
            raise Abort(f'{path.name}: mutant {m["id"]}: old and new are the same')
        tests = m['tests']
        if isinstance(tests, str) or not tests or not all(isinstance(t, str) for t in tests) \
                or not positional(tests):
            raise Abort(f'{path.name}: mutant {m["id"]}: tests must be a list of pytest arguments '
                        'naming at least one test file or node id')
    return mutants


def select(mutants: list, only: str | None) -> list:
    if not only:
        return mutants
    wanted = [x.strip() for x in only.split(',') if x.strip()]
    known = {m['id'] for m in mutants}
    unknown = [x for x in wanted if x not in known]
    if unknown:
        raise Abort(f'--only: unknown mutant {unknown[0]!r}: allowed: the ids that --list prints')
    return [m for m in mutants if m['id'] in wanted]


def site_packages(repo: Path) -> Path | None:
    found = sorted((repo / 'install' / PKG / 'lib').glob('python3*/site-packages'))
    return found[0] if len(found) == 1 else None


def targets(repo: Path, mutant: dict) -> list:
    """The files a mutant changes in ``repo``: the source file, and the install tree's copy of a
    package file."""
    paths = [repo / mutant['file']]
    site = site_packages(repo)
    if mutant['file'].startswith(PKG + '/') and site is not None:
        paths.append(site / mutant['file'])
    return paths


def snippet_problem(path: Path, old: str) -> str:
    """'' if ``old`` occurs exactly once in ``path``, else why not."""
    try:
        text = path.read_text(encoding='utf-8')
    except OSError as exc:
        return f'cannot read {path}: {exc.strerror}'
    n = text.count(old)
    return '' if n == 1 else f'snippet found {n} times in {path} (must be exactly once)'


# --- the copy ------------------------------------------------------------------------------------

def make_copy(root: Path) -> tuple:
    """Copy the repository into ``root``; returns (repo copy, notes)."""
    repo = root / TOP.name

    def ignore(directory, names):
        skip = {n for n in names if n in CACHES}
        if Path(directory) == TOP:
            skip |= {n for n in names if n in EXCLUDED_TOP}
        return skip

    shutil.copytree(TOP, repo, symlinks=True, ignore=ignore)
    for name in SIBLINGS:
        if (TOP.parent / name).exists():
            (root / name).symlink_to(TOP.parent / name)
    notes = []
    site = site_packages(repo)
    if site is None or not (site / PKG).is_dir():
        raise Abort(f'no install tree in {TOP}/install ({PKG}/lib/python3*/site-packages/{PKG}): run make build')
    stale = []
    source = repo / PKG
    for path in sorted(source.rglob('*')):
        if path.is_dir() or CACHES & set(path.relative_to(source).parts):
            continue
        installed = site / PKG / path.relative_to(source)
        if not installed.is_file() or not filecmp.cmp(path, installed, shallow=False):
            stale.append(path.relative_to(repo))
            installed.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(path, installed)
    if stale:
        notes.append(f'install/ was not a copy of the source for {len(stale)} file(s) '
                     f'({", ".join(map(str, stale[:5]))}{" ..." if len(stale) > 5 else ""}): '
                     'refreshed from the source in the copy (make build does the same)')
    return repo, notes


def test_environment(root: Path, repo: Path) -> dict:
    """The Makefile's ROS environment (as /tmp/rt.sh sets it), pointed at the copy."""
    env = dict(os.environ)
    for name in ('ZEROSHOT_ROS_FREE_ONLY', 'ROS_HOME', 'PYTHONHOME'):
        env.pop(name, None)
    inherited = [p for p in env.get('PYTHONPATH', '').split(os.pathsep)
                 if p and not Path(p).resolve().is_relative_to(TOP)]
    home = root / 'home'
    home.mkdir(exist_ok=True)
    profile = str(repo / 'config' / 'fastdds_shm.xml')
    env.update(
        PYTHONPATH=os.pathsep.join([str(site_packages(repo))] + inherited),
        AMENT_PREFIX_PATH=os.pathsep.join([str(repo / 'install' / PKG), str(TOP / '.venv')]),
        ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', RMW_IMPLEMENTATION='rmw_fastrtps_cpp',
        ROS_DOMAIN_ID=env.get('ROS_DOMAIN_ID') or '42',
        FASTDDS_DEFAULT_PROFILES_FILE=profile, FASTRTPS_DEFAULT_PROFILES_FILE=profile,
        PYTHONDONTWRITEBYTECODE='1',  # no .pyc of a mutant can outlive it
        HOME=str(home))
    return env


# --- running pytest --------------------------------------------------------------------------------

_REPORT_LINE = re.compile(r'^(FAILED|ERROR) (.+?)(?: - .*)?$')


def run_pytest(python: str, args: list, repo: Path, env: dict, timeout: float | None, log: Path) -> tuple:
    """(return code or None on timeout, seconds, output). The run is a process group of its own,
    so that a timeout also ends the node processes its tests started."""
    start = time.monotonic()
    with open(log, 'w') as out:
        out.write('$ ' + ' '.join([python, '-m', 'pytest'] + args) + '\n')
        out.flush()
        process = subprocess.Popen([python, '-m', 'pytest'] + args, cwd=repo, env=env, stdout=out,
                                   stderr=subprocess.STDOUT, start_new_session=True)
        try:
            rc = process.wait(timeout)
        except subprocess.TimeoutExpired:
            rc = None
        except BaseException:
            _end_group(process)
            raise
        _end_group(process)
    return rc, time.monotonic() - start, log.read_text(errors='replace')


def _end_group(process):
    """End what is left of the run's process group (all of it after a timeout or an interrupt;
    after a normal exit only processes its tests left behind)."""
    try:
        pgid = os.getpgid(process.pid) if process.poll() is None else process.pid
    except ProcessLookupError:
        pgid = process.pid
    for sig, wait in ((signal.SIGTERM, 5.0), (signal.SIGKILL, 5.0)):
        try:
            os.killpg(pgid, sig)
        except (ProcessLookupError, PermissionError):
            break
        try:
            process.wait(wait)
        except subprocess.TimeoutExpired:
            continue
        if sig == signal.SIGTERM:
            time.sleep(0.2)  # children of the group get the same signal; give them a moment
    if process.poll() is None:
        process.wait()


def reported(output: str) -> list:
    """[(FAILED or ERROR, test id)] from pytest's short summary."""
    found = []
    for line in output.splitlines():
        match = _REPORT_LINE.match(line.strip())
        if match:
            found.append((match.group(1), match.group(2)))
    return found


def last_line(output: str) -> str:
    lines = [line.strip() for line in output.splitlines() if line.strip()]
    return lines[-1] if lines else '(no output)'


def collect(python: str, args: list, repo: Path, env: dict, logs: Path, name: str) -> tuple:
    """(node ids, error) of a test selection with options (e.g. -k)."""
    rc, _, output = run_pytest(python, ['--collect-only', '-q', '-p', 'no:cacheprovider'] + args,
                               repo, env, 600, logs / f'collect-{name}.log')
    ids = [line.strip() for line in output.splitlines() if '::' in line and not line.startswith(('$', 'ERROR'))]
    if rc == 5 or (rc == 0 and not ids):
        return [], 'its tests select nothing: ' + ' '.join(args)
    if rc != 0:
        return [], f'collecting its tests failed (pytest status {rc}): {last_line(output)}'
    return ids, ''


def missing_test(repo: Path, arg: str) -> str:
    """Why a test file or node id of a mutant does not exist in ``repo`` ('' if it does): a
    renamed or removed test makes its mutant an ERROR, not the baseline fail."""
    path, _, rest = arg.partition('::')
    if not (repo / path).exists():
        return f'{path} does not exist'
    name = rest.split('::')[-1].split('[')[0]
    if name and not re.search(rf'^\s*(async\s+)?def {re.escape(name)}\(|^class {re.escape(name)}\b',
                              (repo / path).read_text(errors='replace'), re.M):
        return f'{path} has no test {name}'
    return ''


def baseline_selection(python, mutants, repo, env, logs) -> tuple:
    """(pytest arguments covering every selected mutant's tests once, {mutant id: error})."""
    files, node_ids, errors = [], [], {}
    for m in mutants:
        tests = m['tests']
        missing = [why for why in (missing_test(repo, t) for t in positional(tests)) if why]
        if missing:
            errors[m['id']] = 'stale tests: ' + '; '.join(missing)
            continue
        if any(t.startswith('-') for t in tests):
            ids, error = collect(python, tests, repo, env, logs, m['id'])
            if error:
                errors[m['id']] = error
            node_ids += ids
        else:
            for t in tests:
                (node_ids if '::' in t else files).append(t)
    files = list(dict.fromkeys(files))
    whole = set(files)
    node_ids = [n for n in dict.fromkeys(node_ids) if n.split('::')[0] not in whole]
    return files + node_ids, errors


# --- one mutant -------------------------------------------------------------------------------------

def run_mutant(m: dict, python: str, repo: Path, env: dict, timeout: float, logs: Path) -> dict:
    record = {'id': m['id'], 'behaviour': m['behaviour'], 'result': 'ERROR', 'by': '', 'seconds': 0.0}
    paths = targets(repo, m)
    for path in paths:
        problem = snippet_problem(path, m['old'])
        if problem:
            record['by'] = problem.replace(str(repo) + '/', '')
            return record
    originals = {path: path.read_bytes() for path in paths}
    mutated = {path: data.decode('utf-8').replace(m['old'], m['new'], 1) for path, data in originals.items()}
    for path, text in mutated.items():
        if path.suffix == '.py':
            try:
                compile(text, str(path), 'exec')
            except SyntaxError as exc:  # a broken mutant would be "killed" by any import
                record['by'] = f'the mutated {m["file"]} is not valid Python: {exc.msg} (line {exc.lineno})'
                return record
    try:
        for path, text in mutated.items():
            path.write_bytes(text.encode('utf-8'))
        rc, seconds, output = run_pytest(python, ['-x'] + PYTEST_ARGS + list(m['tests']), repo, env,
                                         timeout, logs / f'{m["id"]}.log')
    finally:
        for path, data in originals.items():
            path.write_bytes(data)
    record['seconds'] = seconds
    failures = reported(output)
    if rc is None:
        record['result'], record['by'] = 'killed (timeout)', f'no result within {timeout:g} s'
    elif rc == 0:
        record['result'] = 'SURVIVED'
    elif rc in (1, 2) and failures:  # 2: interrupted, e.g. the mutant broke an import at collection
        record['result'], record['by'] = 'killed', failures[0][1] + (' (error)' if failures[0][0] == 'ERROR' else '')
    elif rc == 5:
        record['by'] = 'its tests select nothing: ' + ' '.join(m['tests'])
    else:
        record['by'] = f'pytest status {rc}: {last_line(output)}'
    return record


# --- output ------------------------------------------------------------------------------------------

def _cell(text) -> str:
    return str(text).replace('|', '\\|').replace('\n', ' ')


def score(records: list) -> tuple:
    killed = sum(r['result'].startswith('killed') for r in records)
    return killed, len(records)


def table(records: list) -> str:
    lines = ['| mutant | behaviour | result | killed by (first failing test) | s |',
             '|---|---|---|---|---:|']
    for r in records:
        by = r['by']
        shown = f'`{by}`' if r['result'] == 'killed' and by else by
        lines.append(f"| {_cell(r['id'])} | {_cell(r['behaviour'])} | {_cell(r['result'])} | "
                     f"{_cell(shown)} | {r['seconds']:.1f} |")
    killed, total = score(records)
    lines += ['', f'Score: {killed}/{total} ({100.0 * killed / total if total else 0.0:.1f} %) killed']
    for result, what in (('SURVIVED', 'Survived (a documented behaviour no test checks)'),
                         ('ERROR', 'Errors (stale mutants or tests: fix test/mutation/mutants.py)')):
        ids = [r['id'] for r in records if r['result'] == result]
        if ids:
            lines += ['', f'{what}: {", ".join(ids)}']
    return '\n'.join(lines)


def repository_state() -> str:
    try:
        commit = subprocess.run(['git', 'rev-parse', '--short', 'HEAD'], cwd=TOP, capture_output=True,
                                text=True, timeout=10).stdout.strip()
        dirty = subprocess.run(['git', 'status', '--porcelain', '--untracked-files=no'], cwd=TOP,
                               capture_output=True, text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return 'unknown commit'
    return f'commit {commit or "?"}' + (' with uncommitted changes' if dirty else '')


def list_mutants(mutants: list) -> int:
    stale = 0
    for m in mutants:
        # the source only: a run refreshes a stale install tree of its copy from the source
        problems = [p for p in [snippet_problem(TOP / m['file'], m['old'])] if p]
        stale += bool(problems)
        state = 'STALE: ' + '; '.join(p.replace(str(TOP) + '/', '') for p in problems) if problems else 'ok'
        print(f"{m['id']}  [{state}]\n    {m['file']}: {m['behaviour']}\n    tests: {' '.join(m['tests'])}")
    print(f'{len(mutants)} mutants, {stale} stale')
    return 1 if stale else 0


# --- main ----------------------------------------------------------------------------------------------

def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog='mutation.py', description=__doc__.split('\n\n')[0])
    parser.add_argument('--only', metavar='ID[,ID]', help='run only these mutants')
    parser.add_argument('--list', action='store_true', help='list the mutants (and whether each applies) and exit')
    parser.add_argument('--timeout', type=float, default=300.0,
                        help='seconds per mutant; a timeout counts as killed, reported as such (default 300)')
    parser.add_argument('--baseline-timeout', type=float, default=1800.0, help='seconds for the baseline (default 1800)')
    parser.add_argument('--out', metavar='FILE', help='also write the markdown table to FILE')
    parser.add_argument('--python', default=str(TOP / '.venv' / 'bin' / 'python'),
                        help='Python that runs pytest (default: the repository .venv)')
    parser.add_argument('--keep', action='store_true', help='keep the temporary copy and the logs')
    args = parser.parse_args(argv)
    try:
        mutants = select(load_mutants(), args.only)
        if args.list:
            return list_mutants(mutants)
        if not os.access(args.python, os.X_OK):
            raise Abort(f'--python {args.python} is not an executable (make venv creates .venv)')
        if args.timeout <= 0:
            raise Abort(f'--timeout {args.timeout:g} is invalid: allowed: more than 0 seconds')
        return run(args, mutants)
    except Abort as exc:
        print(f'mutation.py: error: {exc}', file=sys.stderr)
        return 2


def run(args, mutants: list) -> int:
    started = time.monotonic()
    root = Path(tempfile.mkdtemp(prefix='zeroshot-mutation-'))
    logs = root / 'logs'
    logs.mkdir()
    interrupted = keep_logs = False
    records = []
    baseline_summary = ''
    state = 'unknown commit'
    try:
        repo, notes = make_copy(root)
        env = test_environment(root, repo)
        state = repository_state()  # what was copied (others may commit during the run)
        print(f'mutation check: {len(mutants)} mutants, copy in {repo} ({state})', flush=True)
        for note in notes:
            print(f'note: {note}', flush=True)

        selection, stale_tests = baseline_selection(args.python, mutants, repo, env, logs)
        print(f'baseline: {len(selection)} test files / ids, unmutated ...', flush=True)
        rc, seconds, output = run_pytest(args.python, PYTEST_ARGS + selection, repo, env,
                                         args.baseline_timeout, logs / 'baseline.log')
        if rc != 0:
            failing = [f'{kind} {name}' for kind, name in reported(output)]
            why = ('timed out' if rc is None else f'pytest status {rc}') + (
                ': ' + '; '.join(failing[:10]) if failing else f': {last_line(output)}')
            keep_logs = True
            raise Abort(f'the baseline (no mutant) fails, {why}: fix the tests first (log: {logs / "baseline.log"})')
        baseline_summary = last_line(output)
        print(f'baseline: {baseline_summary} ({seconds:.0f} s)', flush=True)

        for i, m in enumerate(mutants, start=1):
            if m['id'] in stale_tests:
                record = {'id': m['id'], 'behaviour': m['behaviour'], 'result': 'ERROR',
                          'by': stale_tests[m['id']], 'seconds': 0.0}
            else:
                record = run_mutant(m, args.python, repo, env, args.timeout, logs)
            records.append(record)
            print(f"[{i}/{len(mutants)}] {m['id']}: {record['result']}"
                  + (f" ({record['by']})" if record['by'] else '') + f" {record['seconds']:.1f} s", flush=True)
    except KeyboardInterrupt:
        interrupted = True
        print('interrupted: the table below is partial', file=sys.stderr)
    except Abort as exc:
        print(f'mutation.py: error: {exc}', file=sys.stderr)
        return 2
    finally:
        if args.keep or keep_logs:
            print(f'copy and logs kept in {root}', file=sys.stderr)
        else:
            shutil.rmtree(root, ignore_errors=True)

    elapsed = time.monotonic() - started
    text = table(records)
    print('\n' + text)
    print(f'\n{len(records)} mutants in {elapsed / 60:.1f} min')
    if args.out:
        killed, total = score(records)
        header = [
            '# Mutation check',
            '',
            f'`.venv/bin/python test/mutation/run.py` (`make mutation`) on {state}, '
            f'{datetime.date.today().isoformat()}: {len(records)} curated deliberate bugs '
            '(`test/mutation/mutants.py`), each applied alone to a copy of the repository and its tests '
            f'run; {killed} of {total} killed. Baseline (no mutant): {baseline_summary}. '
            f'Total {elapsed / 60:.1f} min' + (' (interrupted: partial)' if interrupted else '') + '.',
            '',
            '',
        ]
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text('\n'.join(header) + text + '\n')
        print(f'wrote {args.out}')
    if interrupted:
        return 130
    return 0 if all(r['result'].startswith('killed') for r in records) and records else 1


if __name__ == '__main__':
    sys.exit(main())
