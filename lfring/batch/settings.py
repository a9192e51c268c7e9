"""What a batch makes of every frame: :class:`BatchSettings`, its checks, its output names and
the keys that tell a rerun which outputs are still valid."""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass, fields

from lfring.batch.record import made_with
from lfring.core.validate import check_choice, check_fraction, check_int, check_number
from lfring.core.warping import DEFAULT_INTERPOLATION, INTERPOLATIONS
from lfring.depth import ENGINES
from lfring.depth.plan import JUDGED_MIN_PLANES
from lfring.errors import InvalidInputError
from lfring.focus.depth_aware import check_aperture_options, estimation_range
from lfring.focus.methods import METHODS
from lfring.io.writers import json_default

__all__ = ["BatchSettings", "all_in_focus_from_depth_map", "depth_label", "refocus_depth_problem"]

_COMMON_FIELDS = ("calibration_name", "calibration_sha256", "reference", "bit_depth", "encoding", "pattern", "black_level",
                  "white_level")
"""Settings that change every output."""

_DEPTH_FIELDS = ("zmin_m", "zmax_m", "planes", "min_confidence", "depth_method")
"""Settings that change the depth outputs (and the viewer, and an all-in-focus image from the depth map)."""

_REFOCUS_DEPTH_FIELDS = ("zmin_m", "zmax_m", "planes", "depth_method")
"""Settings of the depth map that depth-aware refocusing renders from."""

_EARLIER_DEFAULTS = {"viewer": False, "refocus_method": "shift-and-add", "aperture": None, "f_number": None,
                     "depth_method": "local", "depth": False, "refocus_m": []}
"""What a record's settings mean by a field they lack: :meth:`BatchSettings.describe` leaves
out the viewer when there is none, earlier versions left out the method of shift-and-add, and
records of older versions predate the fields (refocusing was shift-and-add, depth maps the
local sweep)."""

_SETTING_WORDS = {
    "calibration_name": "the calibration", "calibration_sha256": "the calibration's content",
    "reference": "the reference view", "bit_depth": "the bit depth", "encoding": "the encoding",
    "pattern": "the Bayer pattern", "black_level": "the black level", "white_level": "the white level",
    "interpolation": "the interpolation", "refocus_method": "the refocusing method", "aperture": "the aperture",
    "f_number": "f_number", "zmin_m": "zmin_m", "zmax_m": "zmax_m", "planes": "the number of depth planes",
    "min_confidence": "the depth preview's confidence threshold", "depth_method": "the depth method",
    "depths_m": "the depths it chose from", "depth": "the batch's own depth map",
    "from_depth_map": "the all-in-focus image from a depth map",
}
"""How a refusal names each setting that differs between the run that made an output and this
one: in words, or by the parameter name that the command line turns into its option
(``zmin_m`` reads ``--zmin``). The depth cost is no setting (no option gives it; it is the
depth method's default) and is never named."""


def depth_label(z: float) -> str:
    """A refocus depth as its output's kind and file name give it (``refocus_0.5m``): to six
    significant digits, so depths that agree to those make one image."""
    return f"{z:g}"


def refocus_depth_problem(depths) -> str | None:
    """What is wrong with refocus depths in metres, or None: each must be a positive finite
    number, and no two may make the same image.

    The one rule of the batch's refocus depths, for :class:`BatchSettings` and for ``lfring
    batch --refocus``, which both name the setting before it. Infinity is refused: the batch's
    refocusing renders finite depths (``lfring refocus --depth inf`` stands a far finite depth
    for it).

    >>> refocus_depth_problem([0.5, 0.50])
    '0.5 m would be made more than once: give each depth once'
    """
    zs = [float(z) for z in depths]
    for z in zs:
        if math.isinf(z) and z > 0:
            return "the batch cannot refocus at infinity (inf); give a finite depth in metres (lfring refocus --depth inf can)"
        if not z > 0:
            return f"depths must be positive distances in metres, got {z:g}"
    names = [depth_label(z) for z in zs]
    twice = sorted({n for n in names if names.count(n) > 1}, key=float)
    if not twice:
        return None
    close = len(set(zs)) > len(set(names))  # different numbers, one image name
    return (f"{', '.join(f'{n} m' for n in twice)} would be made more than once: give each depth once"
            + (" (images are told apart by the depth to 6 significant digits)" if close else ""))


def _hash(obj) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=json_default).encode()).hexdigest()[:16]


def _range_of(calibration, zmin_m, zmax_m, reference) -> dict:
    """``zmin_m`` and ``zmax_m`` as the depth maps use them: resolved by
    :func:`lfring.focus.depth_aware.estimation_range` when the calibration is known (or both
    are given), else as given (None: the frame's calibration's range, not known here)."""
    if calibration is None:
        if zmin_m is None or zmax_m is None:
            return {"zmin_m": zmin_m, "zmax_m": zmax_m}
        return {"zmin_m": float(zmin_m), "zmax_m": float(zmax_m)}
    try:
        lo, hi = estimation_range(calibration, zmin_m, zmax_m, reference=reference)
    except InvalidInputError:  # the frame fails with this error when it runs; its keys stay as given
        return {"zmin_m": zmin_m, "zmax_m": zmax_m}
    return {"zmin_m": float(lo), "zmax_m": float(hi)}


def all_in_focus_from_depth_map(depth: bool, refocus_m, refocus_method: str) -> bool:
    """Whether a batch's all-in-focus image is made from a depth map: the batch's own
    (``depth``), or the one its refocusing method renders from (depth-aware refocusing at any
    ``refocus_m``), as ``lfring refocus --all-in-focus`` makes it; else by photo-consistency."""
    return bool(depth) or _refocus_from_map(refocus_m, refocus_method)


def _refocus_from_map(refocus_m, refocus_method: str) -> bool:
    """Whether the batch refocuses at any depth by a method that renders from a depth map."""
    return len(refocus_m) > 0 and "depth" in METHODS[refocus_method].options


def _output_parts(d: dict, zrange: dict, *, explained: bool = False) -> dict[str, dict]:
    """Kind -> every setting that changes that output, from settings as
    :meth:`BatchSettings.describe` gives them and the depth range ``zrange``; the outputs' keys
    are their hashes (the structure is that of the keys' first version, so that folders made
    since stay done).

    ``explained``: with the settings that decide which others make an output besides, where its
    key leaves them out (the refocusing method of the refocused images and the viewer, and
    whether the all-in-focus image comes from a depth map): the parts that
    :meth:`BatchSettings.differences` compares."""
    d = {**_EARLIER_DEFAULTS, **d}
    common = {k: d.get(k) for k in _COMMON_FIELDS}
    depth_part = {**{k: d.get(k) for k in _DEPTH_FIELDS}, **zrange}
    if d["depth_method"] == "sgm":
        # The method's default cost: depth maps made before it changed ('lcn' until 'lcn-halves')
        # are not this run's; a resumed folder refuses them unless told to overwrite.
        depth_part["depth_cost"] = ENGINES["sgm"].default_cost
    method = d["refocus_method"]
    refocus_part = {"interpolation": d.get("interpolation")}
    stack = {}
    if METHODS[method].prepare is not None:
        # The method, its aperture and the depth map it used: a folder refocused by another
        # method is not done for this one (shift-and-add's keys stay what they were before
        # methods were a setting, so folders made then stay done for it). The depth map's
        # default cost is left out: images made with an earlier default are kept.
        stack = {"refocus_method": method, "aperture": d["aperture"], "f_number": d["f_number"]}
        refocus_part.update(stack, depth={k: depth_part[k] for k in _REFOCUS_DEPTH_FIELDS})
    zs = [float(z) for z in d["refocus_m"]]
    if explained:
        refocus_part["refocus_method"] = stack["refocus_method"] = method
    parts = {f"refocus_{depth_label(z)}m": {**common, "refocus_m": z, **refocus_part} for z in zs}
    if d.get("all_in_focus"):
        # From a depth map, the batch's own or the one depth-aware refocusing renders from: the
        # same map, so one key whichever made it.
        from_map = all_in_focus_from_depth_map(d["depth"], zs, method)
        source = {"depth": depth_part} if from_map else {"depths_m": zs} if len(zs) > 1 else {"depths_m": "calibrated range"}
        parts["all_in_focus"] = {**common, "all_in_focus": source, **({"from_depth_map": from_map} if explained else {})}
    if d["depth"]:
        for kind in ("depth", "confidence", "depth_preview"):
            parts[kind] = {**common, **depth_part, "kind": kind}
    if d["viewer"]:
        parts["viewer"] = {**common, **depth_part, "kind": "viewer", "depth": d["depth"], **stack}
    return parts


def _leaves(obj, name: str = "") -> dict:
    """A nested dict's values by their own key (``{'depth': {'zmin_m': 0.3}}`` -> ``{'zmin_m': 0.3}``)."""
    if isinstance(obj, dict):
        out = {}
        for k, v in obj.items():
            out.update(_leaves(v, k))
        return out
    return {name: obj}


def _shown(name: str, value) -> str:
    """The value of setting ``name`` as a refusal shows it: None (not given) as its default,
    yes or no, numbers as written, lists as their items (depths with their unit), the
    calibration's content by the start of its hash."""
    if value is None:
        return "default"
    if value is True or value is False:
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.12g}"
    if isinstance(value, (list, tuple)):
        items = ", ".join(_shown(name, v) for v in value)
        return f"{items} m" if name.endswith("_m") else items
    if name == "calibration_sha256":
        return f"sha256 {value[:12]}"
    return str(value)


@dataclass(frozen=True)
class BatchSettings:
    """What to make of every frame.

    Attributes
    ----------
    refocus_m : tuple of float
        Depths in metres to refocus at (one image each).
    refocus_method : {'depth-aware', 'shift-and-add'}
        ``method`` of :func:`lfring.refocus` for those images, and for the viewer's focal stack:
        'depth-aware' (the default, as ``lfring refocus``'s) renders them from the frame's depth
        map, the batch's own when it makes one, else one estimated with ``depth_method`` and
        ``planes`` over ``zmin_m``..``zmax_m`` (by default
        :func:`lfring.focus.depth_aware.estimation_range`, which refuses a calibration that
        gives no range when the settings are made); 'shift-and-add' averages the views.
    aperture, f_number : float, optional
        'depth-aware': the lens's aperture (1, the default: the aperture the views span), or
        the main lens's f-number instead (:func:`lfring.focus.resolve_aperture`); each frame's
        record holds the aperture that made its images.
    depth : bool
        Also compute a depth map over ``zmin_m``..``zmax_m``.
    zmin_m, zmax_m : float, optional
        The depth range in metres of every depth map the batch estimates (``depth``'s, the one
        depth-aware refocusing renders from, the viewer's); by default
        :func:`lfring.focus.depth_aware.estimation_range`'s, the one rule of every entry point
        (``lfring depth``, ``lfring refocus``): the calibration's valid range, its far end derived
        when it has none.
    all_in_focus : bool
        Also write an all-in-focus image: from the depth map when there is one (the batch's own
        with ``depth``, else the one depth-aware refocusing renders from;
        :func:`all_in_focus_from_depth_map`), else over the refocus depths when there are two
        or more, else over the calibrated range.
    calibration : RingCalibration, optional
        None: the built-in calibration for each frame's size.
    calibration_name : str
    reference : 'center' or int
    interpolation : {'cubic', 'linear'}
    bit_depth : {8, 16}
    encoding : {'srgb', 'linear'}
    planes : int, optional
        Number of depth hypotheses (default: at most 1 px of view motion apart).
    depth_method : {'sgm', 'local'}
        ``method`` of :func:`lfring.estimate_depth` for the depth maps, with its default cost (the
        cost is part of the depth outputs' keys, so maps made with an earlier default are not
        taken for this run's).
    min_confidence : float
        Depth preview: pixels below it are black.
    viewer : bool
        Also write an interactive HTML viewer (:mod:`lfring.viewer`), its depth range
        ``zmin_m``..``zmax_m``.
    pattern, black_level, white_level : optional
        Bayer pattern and levels in counts for frames that lack them (they win over sidecars;
        see :func:`lfring.io.levels.load_frame`).
    check_frames : bool
        Refuse frames that do not look like ring frames for the calibration
        (:func:`lfring.check.check_frame`).
    """

    refocus_m: tuple[float, ...] = ()
    refocus_method: str = "depth-aware"
    aperture: float | None = None
    f_number: float | None = None
    depth: bool = False
    zmin_m: float | None = None
    zmax_m: float | None = None
    all_in_focus: bool = False
    calibration: object = None
    calibration_name: str = "built-in"
    reference: object = "center"
    interpolation: str = DEFAULT_INTERPOLATION
    bit_depth: int = 8
    encoding: str = "srgb"
    planes: int | None = None
    depth_method: str = "sgm"
    min_confidence: float = 0.5
    viewer: bool = False
    pattern: str | None = None
    black_level: object = None
    white_level: float | None = None
    check_frames: bool = True

    def __post_init__(self):
        # The fields are checked, not converted (refocus_m aside): their values as given are part
        # of the outputs' keys, which earlier runs' records hold.
        zs = tuple(float(z) for z in self.refocus_m)
        object.__setattr__(self, "refocus_m", zs)
        problem = refocus_depth_problem(zs)
        if problem:
            raise InvalidInputError(f"refocus_m: {problem}")
        if not (zs or self.depth or self.all_in_focus or self.viewer):
            raise InvalidInputError("nothing to do: ask for refocus depths, a depth map, an all-in-focus image or a viewer")
        for name in ("zmin_m", "zmax_m"):
            check_number(getattr(self, name), name, above=0.0, allow_none=True, what="a positive number of metres")
        if self.zmin_m is not None and self.zmax_m is not None and not self.zmin_m < self.zmax_m:
            raise InvalidInputError(f"zmin_m ({self.zmin_m}) must be smaller than zmax_m ({self.zmax_m})")
        check_choice(self.interpolation, "interpolation", INTERPOLATIONS)
        check_choice(self.bit_depth, "bit_depth", (8, 16))
        check_choice(self.encoding, "encoding", ("srgb", "linear"))
        check_choice(self.depth_method, "depth_method", ENGINES)
        check_choice(self.refocus_method, "refocus_method", METHODS)
        if "aperture" in METHODS[self.refocus_method].options:
            check_aperture_options(self.aperture, self.f_number)
        elif self.aperture is not None or self.f_number is not None:
            owners = ", ".join(f"refocus_method={m.name!r}" for m in METHODS.values() if "aperture" in m.options)
            raise InvalidInputError(f"aperture and f_number are for {owners}")
        if (self.aperture is not None or self.f_number is not None) and not (zs or self.viewer):
            raise InvalidInputError("aperture and f_number set the depth of field of refocused images and of the viewer's "
                                    "focal stack: give refocus_m or viewer=True (depth maps and all-in-focus images have "
                                    "no depth of field)")
        # Every depth map (the batch's own, the one depth-aware refocusing renders from, the
        # viewer's) is estimated over depth-aware refocusing's range: a calibration that gives
        # none is refused here, before any frame is read or any file written.
        renders_from_map = _refocus_from_map(zs, self.refocus_method)
        needs_range = self.depth or self.viewer or renders_from_map
        if needs_range and self.calibration is not None:
            estimation_range(self.calibration, self.zmin_m, self.zmax_m, reference=self.reference)
        # The viewer's depth map, when the batch makes none, is the semi-global default; the
        # batch's own and the one depth-aware refocusing renders from follow depth_method.
        if self.planes is not None:
            check_int(self.planes, "planes", minimum=JUDGED_MIN_PLANES, hint=" (a depth is judged against the others)")
        check_fraction(self.min_confidence, "min_confidence")

    def outputs(self, stem: str) -> dict[str, str]:
        """Kind -> output path relative to OUTDIR, for a frame whose relative stem is ``stem``."""
        out = {f"refocus_{depth_label(z)}m": f"{stem}_refocus_{depth_label(z)}m.png" for z in self.refocus_m}
        if self.all_in_focus:
            out["all_in_focus"] = f"{stem}_all_in_focus.png"
        if self.depth:
            out["depth"] = f"{stem}_depth.tiff"
            out["confidence"] = f"{stem}_confidence.tiff"
            out["depth_preview"] = f"{stem}_depth_preview.png"
        if self.viewer:
            out["viewer"] = f"{stem}_viewer.html"
        return out

    def depth_range_m(self, calibration=None) -> tuple[float, float] | None:
        """The depth range in metres of the depth maps made for a frame with ``calibration``
        (default: the settings' own), by :func:`lfring.focus.depth_aware.estimation_range`.

        Returns
        -------
        (float, float) or None
            None when it cannot be told here: no calibration and not both ends given, or a
            calibration that gives no range (the frame then fails with that error).
        """
        cal = self.calibration if calibration is None else calibration
        r = _range_of(cal, self.zmin_m, self.zmax_m, self.reference)
        return None if r["zmin_m"] is None or r["zmax_m"] is None else (r["zmin_m"], r["zmax_m"])

    def output_keys(self, calibration=None, *, resolved: bool = True) -> dict[str, str]:
        """Kind -> a short hash of every setting that changes that output: a rerun that adds an
        output (another refocus depth, a depth map) recomputes only the outputs whose key is new.

        Parameters
        ----------
        calibration : RingCalibration, optional
            The frame's calibration, when the settings hold none (the built-in one for its size).
        resolved : bool
            True: the depth range is the one the depth maps are estimated over
            (:meth:`depth_range_m`, where it can be told), so a range given as the
            calibration's own keys the same outputs as no range, as it makes the same images.
            False: the range as given, as records of earlier versions hold it.
        """
        if resolved:
            cal = self.calibration if calibration is None else calibration
            zrange = _range_of(cal, self.zmin_m, self.zmax_m, self.reference)
        else:
            zrange = {"zmin_m": self.zmin_m, "zmax_m": self.zmax_m}
        return {kind: _hash(part) for kind, part in _output_parts(self.describe(), zrange).items()}

    def differences(self, kind: str, record: dict, calibration=None) -> list[str]:
        """What differs, for output ``kind``, between the settings that made it (an earlier run's
        ``record``) and these, each as ``'name (X then, Y now)'``, X as that run had it.

        Only settings that made the output then and would make it now are named: a setting
        that plays a part on one side only (the depth range of depth-aware images, when the
        earlier ones were shift-and-add) is no difference of its own; the one that decides
        (the refocusing method) is named instead. The calibration's content is named only when
        its name is the same.

        The settings that made the output are the record's own, or those of the earlier run it
        names for the output (:func:`lfring.batch.record.made_with`). Empty when the record
        cannot tell: a record from before outputs named their runs, whose settings are those
        of a later run than the one that made the output, or what differs is no setting (an earlier lfring's default depth
        cost, say); the caller then says so in general words.
        """
        earlier = made_with(record, kind, run=False)
        made = (record.get("output_keys") or {}).get(kind) or (record.get("pending_keys") or {}).get(kind)
        if not isinstance(earlier, dict) or not made:
            return []
        now_d = self.describe()
        cal = self.calibration if calibration is None else calibration
        try:
            now = _output_parts(now_d, _range_of(cal, self.zmin_m, self.zmax_m, self.reference), explained=True)[kind]
            same_cal = all(earlier.get(k) == now_d[k] for k in ("calibration_name", "calibration_sha256"))
            zmin, zmax = earlier.get("zmin_m"), earlier.get("zmax_m")
            ranges = [{"zmin_m": zmin, "zmax_m": zmax}]
            if same_cal:
                ranges.insert(0, _range_of(cal, zmin, zmax, earlier.get("reference", self.reference)))
            made_over = next((r for r in ranges if _hash(_output_parts(earlier, r).get(kind)) == made), None)
            if made_over is None:
                return []
            then = _output_parts(earlier, made_over, explained=True)[kind]
        except (KeyError, TypeError, ValueError, InvalidInputError):  # settings of another version: cannot tell
            return []
        a, b = _leaves(then), _leaves(now)
        names = [n for n in sorted(set(a) & set(b)) if a[n] != b[n]]
        if "calibration_name" in names:  # another calibration: its content differs too, say so once
            names = [n for n in names if n != "calibration_sha256"]
        return [f"{_SETTING_WORDS.get(n, n)} ({_shown(n, a[n])} then, {_shown(n, b[n])} now)" for n in names]

    def describe(self) -> dict:
        """The settings as JSON-ready values (the calibration by name and content hash), as a
        frame's record holds them: the refocusing method always, so that the record names the
        method that made its images (records of earlier versions leave shift-and-add out)."""
        d = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "calibration"}
        d["refocus_m"] = list(self.refocus_m)
        if not self.viewer:  # keeps the keys of folders made before the viewer existed
            del d["viewer"]
        if isinstance(self.black_level, tuple):
            d["black_level"] = list(self.black_level)
        d["calibration_sha256"] = None
        if self.calibration is not None:
            blob = json.dumps(self.calibration.to_dict(), sort_keys=True, default=json_default).encode()
            d["calibration_sha256"] = hashlib.sha256(blob).hexdigest()
        return d

    def legacy_key(self) -> str | None:
        """:meth:`key` as lfring computed it before raw levels and the frame check were settings
        (records of that time carry it), or None when those settings are not at their defaults.
        It leaves the refocusing method out: those records' images (shift-and-add, then) are
        taken as done for either method; ``--overwrite`` redoes them."""
        new = ("pattern", "black_level", "white_level", "check_frames", "depth_method", "refocus_method", "aperture", "f_number")
        if any(getattr(self, n) is not None for n in new[:3]) or not self.check_frames:
            return None
        if self.depth and self.depth_method != "local":  # that version's depth maps came from the local sweep
            return None
        d = {k: v for k, v in self.describe().items() if k not in new}
        return hashlib.sha256(json.dumps(d, sort_keys=True, default=json_default).encode()).hexdigest()[:16]

    def key(self) -> str:
        """A short hash of everything that changes the outputs (computed once per instance)."""
        k = self.__dict__.get("_key")
        if k is None:
            blob = json.dumps(self.describe(), sort_keys=True, default=json_default).encode()
            k = hashlib.sha256(blob).hexdigest()[:16]
            object.__setattr__(self, "_key", k)  # frozen: a memo, not a field
        return k
