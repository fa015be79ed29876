"""NC dialects: what one control family takes, read from a YAML file (``config/nc/<name>.yaml``).

A dialect is data, not code: the post-processor (:mod:`.post`) writes every
program from it and its final check holds the program to it. A machine picks
its dialect in the machine YAML's ``nc:`` section (``dialect: <name or path>``,
``structure: subprograms | flat``). Keys and units are described in
``config/nc/iso_fanuc.yaml``; every shipped value names its source there
(``docs/notes/nc-dialect-sources.md`` has the full references).
"""

import re
from dataclasses import dataclass
from pathlib import Path

import yaml

from ..errors import EdmError, ErrorCode

#: where the shipped dialects live
DIALECT_DIR = Path(__file__).resolve().parents[2] / "config" / "nc"
DEFAULT_DIALECT = "iso_fanuc"
#: feed units a dialect's F can carry: 1/min per block (Fanuc G93), seconds per block (ISG G93), mm/min
FEED_UNITS = ("inverse_min", "block_seconds", "mm_per_min")
STRUCTURES = ("subprograms", "flat")


@dataclass(frozen=True)
class FeedMode:
    """One feed mode: its G code, the unit of its F word and the range the control accepts."""

    code: str
    unit: str
    min: float
    max: float

    def value(self, seconds, length_mm=0.0):
        """The F of a block that takes ``seconds`` (and moves ``length_mm`` on the linear axes)."""
        if self.unit == "inverse_min":
            return 60.0 / seconds
        if self.unit == "block_seconds":
            return seconds
        return 60.0 * length_mm / seconds

    def seconds(self, f, length_mm=0.0):
        """The block time of an F (inverse of :meth:`value`)."""
        if self.unit == "inverse_min":
            return 60.0 / f
        if self.unit == "block_seconds":
            return f
        return 60.0 * length_mm / f


@dataclass(frozen=True)
class Dialect:
    """A control family's NC words and limits (see ``config/nc/iso_fanuc.yaml`` for each key)."""

    name: str
    description: str
    percent_lines: bool
    line_max: int
    program_start: str            # template: {number} {name}
    program_number: int
    subprogram_first: int
    program_number_max: int
    safety_line: str
    program_end: str
    block_numbers: bool
    block_start: int
    block_increment: int
    block_max: int
    linear_decimals: int
    rotary_decimals: int
    feed_decimals: int
    linear_feed: FeedMode
    rotary_feed: FeedMode
    merge_tolerance: float        # mm (rotary axes x rotary_lever)
    rotary_lever: float           # mm/rad
    comment_open: str
    comment_close: str
    comment_upper: bool
    comment_allowed: str          # a regex character class body
    comment_max: int
    tool_change_before: tuple
    tool_change: str              # template: {tool}
    tool_change_after: tuple      # templates: {tool} {work_offset}
    work_offsets: tuple
    positioning: str              # the rapid code for the moves from the tool changer
    subprogram_start: str         # template: {number} {name}; '' : no subprograms
    subprogram_call: str          # template: {number}
    subprogram_return: str
    subprogram_placement: str     # after_main | before_main
    channel_shift: str            # template: {a}; '' : none
    channel_shift_cancel: str
    condition_select: str         # template: {code}; '' : the control has no word (named in a comment)
    generator_on: str
    generator_off: str
    flushing_on: str
    flushing_off: str
    source: str = ""
    axis_decimals: tuple = ()     # ((axis, decimals), ...): per-axis overrides of linear/rotary

    @property
    def subprograms(self):
        return bool(self.subprogram_start and self.subprogram_call and self.subprogram_return and self.channel_shift)

    def comment(self, text):
        """A comment the control takes: case, characters and length of the dialect (cut, never refused)."""
        body = str(text).upper() if self.comment_upper else str(text)
        body = re.sub(f"[^{self.comment_allowed}]", "_", body)
        return f"{self.comment_open}{body[:self.comment_max]}{self.comment_close}"

    def decimals(self, axis):
        own = dict(self.axis_decimals).get(axis)
        if own is not None:
            return own
        return self.linear_decimals if axis in "XYZ" else self.rotary_decimals


def _need(doc, path, kind, source):
    node = doc
    for key in path.split("."):
        if not isinstance(node, dict) or key not in node:
            raise EdmError(ErrorCode.INVALID_REQUEST, f"{source}: missing key {path}")
        node = node[key]
    if kind is str:
        node = "" if node is None else node
    if kind is float and isinstance(node, int) and not isinstance(node, bool):
        node = float(node)
    if not isinstance(node, kind) or isinstance(node, bool) and kind is not bool:
        raise EdmError(ErrorCode.INVALID_REQUEST, f"{source}: {path} must be {kind.__name__}, got {node!r}")
    return node


def _feed(doc, key, source):
    mode = FeedMode(_need(doc, f"feed.{key}.code", str, source), _need(doc, f"feed.{key}.unit", str, source),
                    _need(doc, f"feed.{key}.min", float, source), _need(doc, f"feed.{key}.max", float, source))
    if mode.unit not in FEED_UNITS:
        raise EdmError(ErrorCode.INVALID_REQUEST, f"{source}: feed.{key}.unit must be one of {FEED_UNITS}")
    if not 0 < mode.min < mode.max:
        raise EdmError(ErrorCode.INVALID_REQUEST, f"{source}: feed.{key}: need 0 < min < max, got {mode}")
    return mode


def parse_dialect(doc, source="<dialect>"):
    """A Dialect from a parsed YAML document; INVALID_REQUEST naming the key on anything missing or wrong."""
    if not isinstance(doc, dict):
        raise EdmError(ErrorCode.INVALID_REQUEST, f"{source}: a dialect is a mapping, got {type(doc).__name__}")
    s = lambda p: _need(doc, p, str, source)      # noqa: E731
    i = lambda p: _need(doc, p, int, source)      # noqa: E731
    f = lambda p: _need(doc, p, float, source)    # noqa: E731
    b = lambda p: _need(doc, p, bool, source)     # noqa: E731
    tc = doc.get("tool_change") or {}
    d = Dialect(
        name=s("name"), description=s("description"), percent_lines=b("file.percent_lines"), line_max=i("file.line_max"),
        program_start=s("program.start"), program_number=i("program.main_number"),
        subprogram_first=i("program.first_subprogram_number"), program_number_max=i("program.number_max"),
        safety_line=s("program.safety_line"), program_end=s("program.end"),
        block_numbers=b("block_numbers.enabled"), block_start=i("block_numbers.start"),
        block_increment=i("block_numbers.increment"), block_max=i("block_numbers.max"),
        linear_decimals=i("decimals.linear"), rotary_decimals=i("decimals.rotary"), feed_decimals=i("decimals.feed"),
        linear_feed=_feed(doc, "linear_only", source), rotary_feed=_feed(doc, "rotary", source),
        merge_tolerance=f("feed.merge_tolerance_mm"), rotary_lever=f("feed.rotary_lever_mm_rad"),
        comment_open=s("comments.open"), comment_close=s("comments.close"), comment_upper=b("comments.upper_case"),
        comment_allowed=s("comments.allowed"), comment_max=i("comments.max_length"),
        tool_change_before=tuple(str(v) for v in tc.get("before") or ()), tool_change=s("tool_change.change"),
        tool_change_after=tuple(str(v) for v in tc.get("after") or ()),
        work_offsets=tuple(str(v) for v in _need(doc, "work_offsets", list, source)),
        positioning=s("positioning"),
        subprogram_start=s("subprograms.start"), subprogram_call=s("subprograms.call"),
        subprogram_return=s("subprograms.return"), subprogram_placement=s("subprograms.placement"),
        channel_shift=s("subprograms.channel_shift"), channel_shift_cancel=s("subprograms.channel_shift_cancel"),
        condition_select=s("edm.condition_select"), generator_on=s("edm.generator_on"),
        generator_off=s("edm.generator_off"), flushing_on=s("edm.flushing_on"), flushing_off=s("edm.flushing_off"),
        source=str(source),
        axis_decimals=tuple((a, _need(doc, f"decimals.{a}", int, source)) for a in "XYZABC"
                            if a in (doc.get("decimals") or {})))
    if not all(0 <= v <= 6 for _, v in d.axis_decimals + (("", d.linear_decimals), ("", d.rotary_decimals),
                                                          ("", d.feed_decimals))):
        raise EdmError(ErrorCode.INVALID_REQUEST, f"{source}: decimals must be 0..6")
    if d.subprogram_placement not in ("after_main", "before_main"):
        raise EdmError(ErrorCode.INVALID_REQUEST, f"{source}: subprograms.placement must be after_main or before_main")
    if d.block_numbers and not 0 < d.block_start <= d.block_max:
        raise EdmError(ErrorCode.INVALID_REQUEST, f"{source}: block_numbers: need 0 < start <= max")
    if not d.work_offsets:
        raise EdmError(ErrorCode.INVALID_REQUEST, f"{source}: work_offsets: at least one")
    try:
        re.compile(f"[^{d.comment_allowed}]")
    except re.error as exc:
        raise EdmError(ErrorCode.INVALID_REQUEST, f"{source}: comments.allowed is no character class: {exc}") from None
    if d.comment_open in d.comment_allowed or (d.comment_close and d.comment_close in d.comment_allowed):
        raise EdmError(ErrorCode.INVALID_REQUEST, f"{source}: comments.allowed must not admit the comment brackets")
    return d


def load_dialect(spec=DEFAULT_DIALECT):
    """A shipped dialect by name (``config/nc/<name>.yaml``) or a dialect file by path.

    Raises
    ------
    EdmError
        INVALID_REQUEST for an unknown name (the shipped ones listed), FILE_ERROR for an unreadable file.
    """
    path = Path(spec)
    if path.suffix not in (".yaml", ".yml"):
        path = DIALECT_DIR / f"{spec}.yaml"
        if not path.is_file():
            known = sorted(p.stem for p in DIALECT_DIR.glob("*.yaml"))
            raise EdmError(ErrorCode.INVALID_REQUEST, f"unknown NC dialect {spec!r}: shipped are {known}, or give "
                                                      f"the path of a dialect YAML file")
    try:
        doc = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise EdmError(ErrorCode.FILE_ERROR, f"{path}: {exc.strerror or exc}") from None
    except yaml.YAMLError as exc:
        raise EdmError(ErrorCode.INVALID_REQUEST, f"{path}: malformed YAML: {exc}") from None
    return parse_dialect(doc, str(path))
