"""``python -m gazepipe.synth OUT_DIR [--seed N] [--skeleton four] [--label-swaps N] ...``: write a session like
the bundled sample (:func:`gazepipe.synth.session.sample_config`), with its ground truth under ``OUT_DIR/truth``.

The options make it harder, as real capture is: another markerset (four segments in y-up lab axes), label swaps,
occlusion bursts, clapper hazards, another mocap rate, no head camera or eye tracking. Without them it writes the bundled sample
byte for byte."""

from __future__ import annotations

import argparse
import dataclasses

from gazepipe.synth.session import generate_session, sample_config
from gazepipe.synth.skeleton import FOUR_SEGMENTS

#: the markersets the command line offers: name → (segments with markers, the lab's up axis); None keeps the
#: sample's ten segments in z-up axes
SKELETONS: dict[str, tuple[tuple[str, ...], str] | None] = {"ten": None, "four": (FOUR_SEGMENTS, "y")}


def _config(a: argparse.Namespace):
    cfg = sample_config()
    skeleton = SKELETONS[a.skeleton]
    if skeleton is not None:
        cfg = dataclasses.replace(cfg, segments=skeleton[0], up_axis=skeleton[1])
    if a.no_eyes:
        cfg = dataclasses.replace(cfg, head_camera=False)
    if a.mocap_rate_hz is not None:
        cfg = dataclasses.replace(cfg, rate_hz=a.mocap_rate_hz)
    return dataclasses.replace(cfg, label_swaps=a.label_swaps, occlusion_bursts=a.occlusion_bursts,
                               clap_hazards=a.clap_hazards)


def _share(text: str) -> float:
    value = float(text)
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"{text} is not a share between 0 and 1")
    return value


def _rate(text: str) -> float:
    value = float(text)
    if not 1.0 <= value <= 1000.0:
        raise argparse.ArgumentTypeError(f"{text} is not a capture rate in Hz (1 to 1000)")
    return value


def _count(text: str) -> int:
    value = int(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"{text} is not a count (0 or more)")
    return value


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m gazepipe.synth", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("out_dir", help="the session folder to write (session.toml, markerset.toml, mocap/, ...)")
    p.add_argument("--seed", type=int, default=0, help="random seed: the same seed and options give the same bytes")
    p.add_argument("--skeleton", choices=sorted(SKELETONS), default="ten",
                   help="markers on the ten segments of Klein's chain in z-up axes (default), or on four "
                        "(pelvis, chest, neck2, head) in y-up axes")
    p.add_argument("--label-swaps", type=_count, default=0, metavar="N",
                   help="stretches per mocap take in which two markers carry each other's names (default 0)")
    p.add_argument("--occlusion-bursts", type=_count, default=0, metavar="N",
                   help="moments per mocap take when a side of the body's markers vanish at once (default 0)")
    p.add_argument("--clap-hazards", type=_share, default=0.0, metavar="SHARE",
                   help="share of gaze_follow takes with a clapper hazard: a weak or hidden clap, video frames "
                        "dropped, the clapper's marker lost (default 0)")
    p.add_argument("--mocap-rate-hz", type=_rate, default=None, metavar="HZ",
                   help="the motion capture rate (default 29.97, the sample's; e.g. 120)")
    p.add_argument("--no-eyes", action="store_true",
                   help="no head camera and no eye tracking (a mocap-only session)")
    a = p.parse_args(argv)
    out = generate_session(a.out_dir, seed=a.seed, config=_config(a))
    print(out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
