#!/usr/bin/env python3
"""Lists the Rust functions longer than a limit, longest first, as 'lines path:line name'.

    tools/long_functions.py [--max N] [DIR...]      # default: --max 150 src crates

A function's length runs from its `fn` line to its closing brace; comments, strings and
character literals are blanked before braces are counted, so a brace inside them does not
count. Exits 1 when some function is over the limit (0 when none is), so it can gate a check.
"""
import argparse
import os
import re
import sys

FN = re.compile(r'^\s*(?:pub(?:\([^)]*\))?\s+)?(?:const\s+)?(?:async\s+)?(?:unsafe\s+)?'
                r'(?:extern\s+"[^"]*"\s+)?fn\s+(\w+)')


def code(line):
    line = re.sub(r'"(?:\\.|[^"\\])*"', '""', line)
    line = re.sub(r"'(?:\\.|[^'\\])'", "''", line)
    return re.sub(r'//.*', '', line)


def functions(path):
    lines = open(path, encoding='utf-8', errors='replace').read().split('\n')
    for i, line in enumerate(lines):
        m = FN.match(line)
        if not m:
            continue
        depth, opened = 0, False
        for j in range(i, len(lines)):
            c = code(lines[j])
            if not opened and ';' in c and '{' not in c:
                break  # a declaration without a body
            depth += c.count('{') - c.count('}')
            opened = opened or '{' in c
            if opened and depth <= 0:
                yield j - i + 1, i + 1, m.group(1)
                break


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--max', type=int, default=150)
    ap.add_argument('dirs', nargs='*', default=['src', 'crates'])
    args = ap.parse_args()
    found = []
    for d in args.dirs:
        for root, _, files in os.walk(d):
            for f in sorted(files):
                if f.endswith('.rs'):
                    p = os.path.join(root, f)
                    found += [(n, f'{p}:{at}', name) for n, at, name in functions(p) if n > args.max]
    for n, at, name in sorted(found, reverse=True):
        print(n, at, name)
    print(f'{len(found)} functions over {args.max} lines', file=sys.stderr)
    return 1 if found else 0


if __name__ == '__main__':
    sys.exit(main())
