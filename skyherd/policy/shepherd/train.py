"""`python -m skyherd.policy.shepherd.train`: fit the learned selector from the Strömbom shepherd's
demonstrations (policy.shepherd.selector.train_selector) and write selector.json."""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

from skyherd.policy.shepherd.selector import SELECTOR_FILE, SelectorFitParams, train_selector


def main(argv: list[str] | None = None) -> int:
    d = SelectorFitParams()
    ap = argparse.ArgumentParser(prog="python -m skyherd.policy.shepherd.train", description=__doc__,
                                 formatter_class=argparse.ArgumentDefaultsHelpFormatter)  # fmt: skip
    ap.add_argument("--first-seed", type=int, default=d.seeds[0], help="first demonstration seed")
    ap.add_argument("--episodes", type=int, default=len(d.seeds), help="demonstration episodes")
    ap.add_argument("--out", default=str(SELECTOR_FILE), help="the selector file to write")
    a = ap.parse_args(argv)
    if a.episodes < 1:
        print("--episodes must be >= 1", file=sys.stderr)
        return 2
    fit = replace(d, seeds=tuple(range(a.first_seed, a.first_seed + a.episodes)))
    sel, rec = train_selector(fit)
    out = Path(a.out)
    tmp = out.with_suffix(".tmp")
    tmp.write_text(json.dumps(sel.to_json(**rec), indent=1) + "\n")
    tmp.replace(out)
    print(f"{out}: {rec['demonstrations']} decisions, train accuracy {rec['train_accuracy']}, "
          f"log-loss {rec['log_loss']}")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
