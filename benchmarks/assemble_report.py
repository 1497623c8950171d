# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Assemble docs/benchmarks.md from the per-issue sections the benchmark scripts write.

Each ``benchmarks/bench_*.py`` writes ``docs/bench/<issue>-<area>.md``; this
script puts ``docs/bench/summary.md`` (the hand-written overview of goals met
and missed) first and every section after it, in issue order.
"""

from pathlib import Path
import sys

REPO = Path(__file__).resolve().parent.parent
SECTIONS = REPO / 'docs' / 'bench'


def main() -> int:
    """Write docs/benchmarks.md; return 0."""
    parts = ['# Benchmarks\n',
             'Every table below is produced by a script in `benchmarks/` (named in its section) '
             'on real recordings from `../shared/data` and on simulated runs. Goals come from '
             'the issues; a missed goal is reported as missed. The machine is a shared 2-core '
             'box: speed figures are medians or ratios measured in one run, and the load at '
             'the time is stated where it mattered.\n']
    summary = SECTIONS / 'summary.md'
    if summary.exists():
        parts.append(summary.read_text())
    for path in sorted(SECTIONS.glob('[0-9]*.md'), key=lambda p: (int(p.name.split('-')[0]),
                                                                  p.name)):
        text = path.read_text().strip()
        text = '\n'.join(('#' + ln) if ln.startswith('#') else ln for ln in text.splitlines())
        parts.append(f'<!-- from docs/bench/{path.name} -->\n{text}\n')
    (REPO / 'docs' / 'benchmarks.md').write_text('\n'.join(parts))
    return 0


if __name__ == '__main__':
    sys.exit(main())
