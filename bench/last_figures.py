#!/usr/bin/env python3
"""Print the figures of the last recorded `make bench` run (docs/benchmarks.md, its first fenced block after
'Figures of'), so that `make bench` puts them before today's: a reader compares the two and tells noise from
regression."""
import re
import sys
import time
from pathlib import Path

PAGE = Path(__file__).resolve().parent.parent / 'docs' / 'benchmarks.md'


def main(page: str = str(PAGE)) -> int:
    text = Path(page).read_text()
    m = re.search(r'^(Figures of [^\n]*)\n.*?```\n(.*?)```', text, re.S | re.M)
    if not m:
        print(f'{page} has no benchmark figures')
        return 0
    rule = '=' * 100
    print(rule)
    print(f'last recorded (docs/benchmarks.md): {m.group(1).rstrip(":")}')
    print(rule)
    print(m.group(2).rstrip())
    print(rule)
    print(f'today ({time.strftime("%Y-%m-%d")}), each reference measured in the same run:')
    print(rule)
    return 0


if __name__ == '__main__':
    sys.exit(main(*sys.argv[1:]))
