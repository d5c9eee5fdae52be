"""``python -m gazepipe.synth OUT_DIR [--seed N]``: write a session like the bundled sample
(:func:`gazepipe.synth.session.sample_config`)."""

from __future__ import annotations

import argparse

from gazepipe.synth.session import generate_session, sample_config


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m gazepipe.synth", description=__doc__)
    p.add_argument("out_dir")
    p.add_argument("--seed", type=int, default=0)
    a = p.parse_args(argv)
    out = generate_session(a.out_dir, seed=a.seed, config=sample_config())
    print(out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
