#!/usr/bin/env python3
# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
How often the suite passes from a fresh clone, as CI runs it, idle or beside busy loops.

Each run clones this repository at --commit into a temporary directory (committed files
only, as CI sees them) and runs `.ci/run` there: a new venv, the pinned install, the whole
suite. With --test, one clone and its venv (`make venv`) serve every run, and each run is one
pytest process of that test alone. --busy-loops K starts K `while True: pass` processes for
the length of each run. Figures, no asserts: a line per run, the count and the durations, and
JSON (--json). Every run's output is kept in --logs. Ctrl-C or SIGTERM stops the run in
progress whole: its processes, its busy loops and its clone.
"""
import argparse
import json
import os
import pathlib
import platform
import re
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import time

REPO = pathlib.Path(__file__).resolve().parents[1]
SUMMARY = re.compile(r'\d+ (passed|failed|errors?)\b.* in [\d.]+s')


def clone(commit, directory):
    """Clone this repository into `directory` and check out `commit`; return its full hash."""
    subprocess.run(['git', 'clone', '--quiet', '--no-hardlinks', str(REPO), str(directory)],
                   check=True)
    subprocess.run(['git', '-C', str(directory), 'checkout', '--quiet', commit], check=True)
    return subprocess.run(['git', '-C', str(directory), 'rev-parse', 'HEAD'], check=True,
                          capture_output=True, text=True).stdout.strip()


def run_logged(command, cwd, env, log_path, busy_loops):
    """Run `command` in `cwd` beside `busy_loops` busy processes; return (exit code, seconds)."""
    loops = [subprocess.Popen([sys.executable, '-c', 'while True: pass'])
             for _ in range(busy_loops)]
    start = time.monotonic()
    try:
        with open(log_path, 'w') as log:
            # A session of its own, so that an interrupted run is stopped whole.
            process = subprocess.Popen(command, cwd=cwd, env=env, stdout=log,
                                       stderr=subprocess.STDOUT, start_new_session=True)
            try:
                code = process.wait()
            except BaseException:
                os.killpg(process.pid, signal.SIGTERM)
                process.wait()
                raise
        return code, time.monotonic() - start
    finally:
        for loop in loops:
            loop.kill()
            loop.wait()


def summary_line(log_path):
    """Pytest's last summary line in the log, or its last line when pytest gave none."""
    lines = log_path.read_text(errors='replace').splitlines()
    found = [line.strip(' =') for line in lines if SUMMARY.search(line)]
    return found[-1] if found else (lines[-1] if lines else '(no output)')


def positive(text):
    """Argparse type: an integer of at least 1."""
    if not text.isdigit() or int(text) < 1:
        raise argparse.ArgumentTypeError(f'{text!r} is not a whole number of at least 1')
    return int(text)


def stop(signum, frame):
    """On SIGTERM, leave as on Ctrl-C: the run's process group and busy loops go too."""
    raise SystemExit(128 + signum)


def main(argv=None):
    """Run the runs, print a line for each and the count, write JSON if asked."""
    signal.signal(signal.SIGTERM, stop)
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--runs', type=positive, default=10)
    parser.add_argument('--busy-loops', type=int, default=0, metavar='K',
                        help='busy processes beside each run (one per core: the loaded count)')
    parser.add_argument('--commit', default='HEAD', help='what to clone (default: HEAD)')
    parser.add_argument('--test', metavar='NODEID',
                        help='run this test alone in one clone instead of `.ci/run` in each')
    parser.add_argument('--logs', type=pathlib.Path, default=pathlib.Path('build/fresh-clone'),
                        help="directory for each run's output (default: build/fresh-clone)")
    parser.add_argument('--json', type=pathlib.Path, help='write the runs here')
    args = parser.parse_args(argv)
    args.logs.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    runs = []
    with tempfile.TemporaryDirectory(prefix='kmd_fresh_clone_') as workdir:
        workdir = pathlib.Path(workdir)
        if args.test:
            checkout = workdir / 'clone'
            commit = clone(args.commit, checkout)
            with open(args.logs / 'venv.log', 'w') as log:
                subprocess.run(['make', 'venv'], cwd=checkout, check=True, env=env, stdout=log,
                               stderr=subprocess.STDOUT)
        else:
            commit = subprocess.run(['git', '-C', str(REPO), 'rev-parse', args.commit],
                                    check=True, capture_output=True, text=True).stdout.strip()
        runs_of = 'a run' if args.runs == 1 else f'{args.runs} runs'
        print(f'{commit[:7]}, {runs_of} of '
              f'{args.test or ".ci/run in a fresh clone"}, {args.busy_loops} busy loops, '
              f'{os.cpu_count()} cores', flush=True)
        for number in range(1, args.runs + 1):
            if args.test:
                command = [str(checkout / '.venv/bin/python'), '-m', 'pytest', '-q', args.test]
            else:
                checkout = workdir / f'clone-{number}'
                clone(commit, checkout)
                command = ['./.ci/run']
            log_path = args.logs / f'run-{number}.log'
            code, seconds = run_logged(command, checkout, env, log_path, args.busy_loops)
            if not args.test:
                shutil.rmtree(checkout)
            runs.append({'run': number, 'exit_code': code, 'seconds': round(seconds, 1),
                         'summary': summary_line(log_path), 'log': str(log_path)})
            print(f'run {number}: {"green" if code == 0 else f"RED (exit {code})"}, '
                  f'{seconds:.0f} s: {runs[-1]["summary"]}', flush=True)
    durations = [run['seconds'] for run in runs]
    green = sum(run['exit_code'] == 0 for run in runs)
    print(f'{green} of {len(runs)} green; whole run min {min(durations):.0f} s, median '
          f'{statistics.median(durations):.0f} s, max {max(durations):.0f} s')
    if args.json:
        args.json.write_text(json.dumps({
            'commit': commit, 'test': args.test, 'busy_loops': args.busy_loops,
            'cores': os.cpu_count(), 'python': platform.python_version(), 'green': green,
            'runs': runs}, indent=2) + '\n')


if __name__ == '__main__':
    main()
