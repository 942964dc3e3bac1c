"""The README's figures, produced by commands rather than copied by hand (`make figures`,
`python -m skyherd.scripts.figures`).

Flies the main job (`skyherd fly --speedup 0`, what `make run` flies) and a flight the judge
fails (the same with a forced disarm in the air), copies the figures of the first into
docs/figures/, screenshots both run folders' report.html in headless Chromium (when the
machine has it: Debian's `chromium`), and writes docs/figures/figures.json: for every figure
the command that drew it, its SHA-256, when and at what load. The README's block between
`<!-- figures:begin -->` and `<!-- figures:end -->` is rewritten from that file
(`readme_block`), so its words are the script's too. tests/test_docs.py checks that every
figure the README shows is listed with its hash, and re-flies the command to check that the
drawn figures are byte for byte what it draws today.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from skyherd.report.figures import OUT, make_figures, write_readme


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m skyherd.scripts.figures", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    ap.add_argument("--out", type=Path, default=OUT, help="where the figures go (docs/figures)")
    ap.add_argument("--instance", type=int, default=0, help="the flights' vehicle instance N")
    ap.add_argument("--no-readme", action="store_true", help="leave README.md as it is")
    args = ap.parse_args(argv)
    made = make_figures(args.out, args.instance)  # report.figures: the flights, the manifest
    if not args.no_readme:
        write_readme(made)
    print(f"figures: {', '.join(made['figures'])} in {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
