"""``gazepipe inspect``: the text summary of a marker capture, an OpenFace CSV or a Live Link Face CSV (the
dictionaries of :mod:`gazepipe.io.inspect_tracks`)."""

from __future__ import annotations

from typing import Any

from gazepipe.errors import printable


def _pct(share: float | None) -> str:
    return "n/a" if share is None else f"{100 * share:.1f} %"


def _rate(info: dict[str, Any]) -> str:
    rate, period = info.get("rate_hz"), info.get("frame_period_s")
    if rate is None:
        return "rate unknown (the timestamps never advance)"
    return f"{rate:.6g} Hz (frame period {period:.6f} s)"


def _duration(info: dict[str, Any]) -> str:
    d = info.get("duration_s")
    return "duration unknown" if d is None else f"{d:.3f} s"


def c3d_storage_text(info: dict[str, Any]) -> str:
    """A C3D's processor, storage (with POINT:SCALE) and analog channels, on one line."""
    scale = info.get("point_scale")
    if info["storage"] == "float":
        storage = "float" + ("" if scale is None else f" (POINT:SCALE {scale:g}, applied to residuals only)")
    else:
        storage = "integer" + ("" if scale is None else f" (POINT:SCALE {scale:g} {info.get('units') or ''} "
                                                         "per unit)".replace("  ", " "))
    n = info.get("analog_channels") or 0
    rate = info.get("analog_rate_hz")
    analog = f"{n} analog channel{'' if n == 1 else 's'}" + (f" at {rate:g} Hz" if n and rate else "")
    return f"processor {info.get('processor', '?')}, storage {storage}, {analog}"


def capture_lines(info: dict[str, Any]) -> list[str]:
    """A marker capture: format, frames, rate, units, then every marker's gap share."""
    lines = [f"  format {info['format']}, {info['frames']} frames at {info['rate_hz']:.6g} Hz, "
             f"first frame {info['first_frame']}, units {info['units'] or 'not stated'}",
             f"  {len(info['markers'])} markers, {len(info['model_outputs'])} model outputs"]
    if info["format"] == "c3d" and "storage" in info:
        lines.insert(1, "  " + c3d_storage_text(info))
    lines += [f"    {printable(m['label']):<24} gaps {100 * m['gap_fraction']:6.2f} %" for m in info["markers"]]
    return lines


def openface_lines(info: dict[str, Any]) -> list[str]:
    """An OpenFace CSV: rows, rate, duration, validity and blink shares."""
    lines = [f"  format OpenFace CSV ({info['layout']}), {info['rows']} rows at {_rate(info)}, "
             f"{_duration(info)}, {info['missing_frames']} video frames without a row",
             f"  valid {_pct(info['valid_share'])} ({info['valid_rule']}); success {_pct(info['success_share'])}"]
    if info["blink_rule"] is None:
        lines.append("  blinks: unknown (no AU45_c or AU45_r column)")
    else:
        lines.append(f"  blinks {_pct(info['blink_share'])} ({info['blink_rule']}, masked by the eyes stage)")
    if info.get("face_id") is not None:
        lines.append(f"  face_id {info['face_id']}")
    return lines


def livelinkface_lines(info: dict[str, Any]) -> list[str]:
    """A Live Link Face CSV: rows, rate, duration, dropped frames, validity, blinks, head tracking."""
    lines = [f"  format Live Link Face CSV, {info['rows']} rows at {_rate(info)}, {_duration(info)}, "
             f"{info['dropped_frames']} dropped frames; timecode from {info['first_timecode']} at "
             f"{info['timecode_fps']:g} fps",
             f"  valid {_pct(info['valid_share'])} ({info['valid_rule']})",
             f"  blinks {_pct(info['blink_share'])} ({info['blink_rule']}; left {_pct(info['blink_left_share'])}, "
             f"right {_pct(info['blink_right_share'])})"]
    if info["head_tracking"]:
        r = info["head_range_deg"]
        lines.append(f"  head tracking on (range yaw {r['yaw']:.1f}°, pitch {r['pitch']:.1f}°, roll {r['roll']:.1f}°)")
    elif info["head_columns"]:
        lines.append("  head tracking off (the head rotation columns are all zero or constant)")
    else:
        lines.append("  head tracking off (no head rotation columns)")
    return lines


def text_lines(info: dict[str, Any]) -> list[str]:
    """Every line ``gazepipe inspect`` prints for ``info``: the path, the summary, the warnings (text taken from
    the file, such as labels, with control characters escaped)."""
    body = {"openface": openface_lines, "livelinkface": livelinkface_lines}.get(info["format"], capture_lines)
    return [printable(line) for line in [info["path"], *body(info), *(f"  warning: {w}" for w in info["warnings"])]]
