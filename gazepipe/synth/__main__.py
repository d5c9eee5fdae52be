"""``python -m gazepipe.synth OUT_DIR [--seed N] [--skeleton four] [--label-swaps N] ...``: write a session like
the bundled sample (:func:`gazepipe.synth.session.sample_config`), with its ground truth under ``OUT_DIR/truth``.

The options make it harder, as real capture is: another markerset (four segments in y-up lab axes), markers the
markerset lists in no segment (shoulders, elbows), label swaps, occlusion bursts, clapper hazards, another mocap rate, a clapper the head camera sees less well, no head camera or
eye tracking. Without them it writes the bundled sample byte for byte.

Exit codes: 0 written; 1 the folder could not be written (read-only, unreachable, full: nothing of the session
is left there); 2 a bad option or OUT_DIR (empty, a file)."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from typing import NoReturn

from gazepipe.synth.session import OutputFolderError, generate_session, sample_config
from gazepipe.synth.skeleton import FOUR_SEGMENTS, UNLISTED_SETS
from gazepipe.synth.video import LOOKS

PROG = "python -m gazepipe.synth"

#: the markersets the command line offers: name → (segments with markers, the lab's up axis); None keeps the
#: sample's ten segments in z-up axes
SKELETONS: dict[str, tuple[tuple[str, ...], str] | None] = {"ten": None, "four": (FOUR_SEGMENTS, "y")}

#: the most label swaps or occlusion bursts a take may be given (a 45 s take holds a few dozen at most)
MAX_COUNT = 1000
#: seeds are whole numbers below 2^64 (numpy's SeedSequence takes them)
MAX_SEED = 2**64 - 1


class _Parser(argparse.ArgumentParser):
    """argparse with its errors on one line (no usage block), exit 2."""

    def error(self, message: str) -> NoReturn:
        _fail(message, 2)


def _fail(message: str, code: int) -> NoReturn:
    print(f"{PROG}: error: {' '.join(str(message).split())}", file=sys.stderr)
    sys.exit(code)


def _config(a: argparse.Namespace):
    cfg = sample_config()
    skeleton = SKELETONS[a.skeleton]
    if skeleton is not None:
        cfg = dataclasses.replace(cfg, segments=skeleton[0], up_axis=skeleton[1])
    if a.no_eyes:
        cfg = dataclasses.replace(cfg, head_camera=False)
    if a.mocap_rate_hz is not None:
        cfg = dataclasses.replace(cfg, rate_hz=a.mocap_rate_hz)
    if a.clapper_look != "sample":
        cfg = dataclasses.replace(cfg, clapper_look=LOOKS[a.clapper_look])
    if a.unlisted_markers:
        cfg = dataclasses.replace(cfg, unlisted_markers=UNLISTED_SETS[a.unlisted_markers],
                                  unlisted_motion=a.unlisted_motion)
    return dataclasses.replace(cfg, label_swaps=a.label_swaps, occlusion_bursts=a.occlusion_bursts,
                               clap_hazards=a.clap_hazards)


def _within(text: str, low: float, high: float, what: str, kind: type = float):
    """``text`` as a ``kind`` (``float`` or ``int``) in ``[low, high]``, else the option's error naming it as
    ``what`` (NaN is in no range)."""
    try:
        value = kind(text.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text[:40]!r} is not {what}") from None
    if not low <= value <= high:
        raise argparse.ArgumentTypeError(f"{text[:40]} is not {what}")
    return value


def _share(text: str) -> float:
    return _within(text, 0.0, 1.0, "a share between 0 and 1")


def _scale(text: str) -> float:
    return _within(text, 0.0, 10.0, "a scale (0 to 10)")


def _rate(text: str) -> float:
    return _within(text, 10.0, 1000.0, "a mocap rate in Hz (10 to 1000)")


def _count(text: str) -> int:
    return _within(text, 0, MAX_COUNT, f"a count (0 to {MAX_COUNT})", int)


def _seed(text: str) -> int:
    return _within(text, 0, MAX_SEED, "a seed (a whole number, 0 or more, below 2^64)", int)


def main(argv: list[str] | None = None) -> int:
    p = _Parser(prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("out_dir", help="the session folder to write (session.toml, markerset.toml, mocap/, ...)")
    p.add_argument("--seed", type=_seed, default=0,
                   help="random seed, 0 or more: the same seed and options give the same bytes")
    p.add_argument("--skeleton", choices=sorted(SKELETONS), default="ten",
                   help="markers on the ten segments of Klein's chain in z-up axes (default), or on four "
                        "(pelvis, chest, neck2, head) in y-up axes")
    p.add_argument("--unlisted-markers", choices=sorted(UNLISTED_SETS), default=None,
                   help="markers in no markerset segment, moving against the chest: the left and right shoulders "
                        "(LSHO, RSHO, 340 mm apart), or the shoulders and the elbows (LELB, RELB); label swaps "
                        "then exchange them too: the mirror pairs, a shoulder and its elbow or the chest's marker "
                        "on its side (default: none)")
    p.add_argument("--unlisted-motion", type=_scale, default=1.0, metavar="SCALE",
                   help="how far the unlisted markers move against the chest, as a multiple of the default "
                        "(20 mm shrugs, 15 mm reaches, 20 degrees of arm swing; default 1, at most 10)")
    p.add_argument("--label-swaps", type=_count, default=0, metavar="N",
                   help=f"stretches per mocap take in which two markers carry each other's names (default 0, at "
                        f"most {MAX_COUNT})")
    p.add_argument("--occlusion-bursts", type=_count, default=0, metavar="N",
                   help=f"moments per mocap take when a side of the body's markers vanish at once (default 0, at "
                        f"most {MAX_COUNT})")
    p.add_argument("--clap-hazards", type=_share, default=0.0, metavar="SHARE",
                   help="share of gaze_follow takes with a clapper hazard: a weak or hidden clap, video frames "
                        "dropped, the clapper's marker lost (default 0)")
    p.add_argument("--mocap-rate-hz", type=_rate, default=None, metavar="HZ",
                   help="the mocap capture rate (default 29.97, as the sample)")
    p.add_argument("--clapper-look", choices=list(LOOKS), default="sample",
                   help="how the head camera sees the clapper: as in the sample (default); smaller (farther away); "
                        "dim and noisy; blurred (a longer exposure, defocus); busy (a hand swinging beside it); "
                        "far (a bit of each)")
    p.add_argument("--no-eyes", action="store_true",
                   help="no head camera and no eye tracking (a mocap-only session)")
    a = p.parse_args(argv)
    try:
        out = generate_session(a.out_dir, seed=a.seed, config=_config(a))
    except OutputFolderError as e:
        _fail(str(e), 2)
    except OSError as e:
        _fail(f"{a.out_dir}: cannot write the session ({e.strerror or type(e).__name__}); nothing of it is left "
              "there", 1)
    print(out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
