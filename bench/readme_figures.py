#!/usr/bin/env python3
"""Print the benchmark figures the README shows (its first fenced block after 'Figures of'), so that `make bench`
puts them before today's: a reader compares the two and tells noise from regression."""
import os
import re
import sys
import time


def main(readme=os.path.join(os.path.dirname(os.path.realpath(__file__)), '..', 'README.md')):
    text = open(readme).read()
    m = re.search(r'^(Figures of [^\n]*)\n.*?```\n(.*?)```', text, re.S | re.M)
    if not m:
        print('the README has no benchmark figures')
        return 0
    print('=' * 100)
    print('README: %s' % m.group(1).rstrip(':'))
    print('=' * 100)
    print(m.group(2).rstrip())
    print('=' * 100)
    print('today (%s), each reference measured in the same run:' % time.strftime('%Y-%m-%d'))
    print('=' * 100)
    return 0


if __name__ == '__main__':
    sys.exit(main(*sys.argv[1:]))
