"""Persistent plans: an SQLite file of certified plans, keyed by request and by plan id.

Every node and the command line share one store directory (by default
``$EDM_PLANNER_PLAN_STORE``, else ``~/.local/share/edm_planner/plan_store``), so a plan outlives the process that
made it: a repeated PlanChannel is answered from the store at once, and the axis
bridge finds a plan by id after a restart without the planner republishing it.

A record keeps what re-serving and executing a plan need, bit for bit: the axis
samples, the poses, the search nodes and the electrode mesh as ``.npy`` arrays,
the rest as JSON, compressed together, with a SHA-256 of the record beside it.

Keys
----
``plan_id``
    The plan's own id (:func:`~edm_planner.planning.planner.plan_id_for`).
``request_key``
    A hash of what a request asked for: the geometry id (itself a SHA-256 of
    the geometry's content), channel, electrode id, settings and electrode
    design as requested. Equal requests find the same plan.

Every record made by :func:`plan_to_stored` and :func:`roughing_to_stored` carries the plan's certificate
digest (``meta["certificate_sha256"]``, :mod:`edm_planner.records.certificate`); :func:`stored_to_plan` and
:func:`plan_cycle_of_stored` refuse a record without one or not matching it (NOT_CERTIFIED).

A channel plan's record also keeps its machining cycle (every leg's phase,
label, samples and certified clearance, the process reach, margin and
verdict), the removal proof of its electrode set and the set's id; records
written before cycles existed load with ``cycle`` None.

Sequences
---------
The ``sequences`` table keeps ordered lists of (plan id, channel) steps, with
the same checksums and transactions: ``electrode_set`` (a set's electrodes in
machining order in one channel) and ``blisk_program`` (each electrode through
every channel 0 .. N-1, then the next; :mod:`edm_planner.machining.program`).
The table is created on first use in a store of schema 1 (older versions of
edm_planner ignore it).

Safety
------
Nothing is ever overwritten or deleted behind the user's back. A file that is
not SQLite, an SQLite file of another application, a newer schema, a failed
integrity check or a record whose checksum does not match raise
:class:`PlanStoreError` (``FILE_ERROR``) naming the file and what to do; the
file is left as it was. Writes are transactions (WAL journal), so a crash
leaves either the old or the new record, and several processes may share the
store.
"""

import datetime
import hashlib
import io
import json
import logging
import os
import pathlib
import shutil
import sqlite3
import zlib
from dataclasses import asdict, dataclass, field

import numpy as np

import trimesh

from .. import __version__
from ..errors import EdmError, ErrorCode
from ..machining.program import PlanCycle
from ..planning.plan import Plan, PlanMetrics, plan_options_from_dict
from .certificate import META_KEY, record_digest, verify_record
from .cycle_record import cycle_from_record, cycle_to_record

log = logging.getLogger(__name__)

APPLICATION = "edm_planner.plan_store"
SCHEMA = 1
FILE_NAME = "plans.sqlite"
#: environment variable naming the store directory of nodes and the command line when not told otherwise
ENV_VAR = "EDM_PLANNER_PLAN_STORE"
#: SQLite's application_id header field, so ``file`` and other tools can tell the file apart ("EDMP")
APPLICATION_ID = 0x45444D50

_SCHEMA_SQL = """
CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE plans (
    plan_id      TEXT PRIMARY KEY,
    request_key  TEXT,
    kind         TEXT NOT NULL,
    geometry_id  TEXT NOT NULL,
    channel      INTEGER NOT NULL,
    electrode_id TEXT NOT NULL,
    method       TEXT NOT NULL,
    created      TEXT NOT NULL,
    version      TEXT NOT NULL,
    sha256       TEXT NOT NULL,
    record       BLOB NOT NULL
);
CREATE INDEX plans_request ON plans (request_key);
"""
_SEQUENCES_SQL = """
CREATE TABLE IF NOT EXISTS sequences (
    sequence_id  TEXT PRIMARY KEY,
    kind         TEXT NOT NULL,
    geometry_id  TEXT NOT NULL,
    created      TEXT NOT NULL,
    version      TEXT NOT NULL,
    sha256       TEXT NOT NULL,
    record       BLOB NOT NULL
)
"""
#: kinds of sequence: an electrode set of one channel, a whole-blisk program
SEQUENCE_KINDS = ("electrode_set", "blisk_program")


def _not_the_file(exc):
    """Whether an SQLite error is of the disk or of other processes (full, I/O, permission, lock), not the file's."""
    return (getattr(exc, "sqlite_errorname", "") or "").startswith(
        ("SQLITE_IOERR", "SQLITE_FULL", "SQLITE_CANTOPEN", "SQLITE_READONLY", "SQLITE_PERM", "SQLITE_BUSY",
         "SQLITE_LOCKED"))


def _disk_note(exc, directory):
    """`` (SQLITE_FULL, 0.0 MB free on its file system)`` of an error of the disk, else ''."""
    if not _not_the_file(exc):
        return ""
    try:
        free = f"{shutil.disk_usage(directory).free / 1e6:.1f} MB"
    except OSError:
        free = "unknown space"
    return f" ({exc.sqlite_errorname}, {free} free on its file system)"


class PlanStoreError(EdmError):
    """The plan store cannot be used (FILE_ERROR); the message names the file and the way out."""

    def __init__(self, message):
        super().__init__(ErrorCode.FILE_ERROR, message)


def request_key(geometry_id, channel, electrode_id, settings, design=None):
    """Key of a planning request: equal requests (same geometry content and settings) give equal keys.

    Parameters
    ----------
    geometry_id : str
        The geometry's content hash.
    channel : int
    electrode_id : str
        As requested ('' for the first electrode).
    settings : dataclass or dict
        The request's options (e.g. :class:`~edm_planner.planning.plan.PlanOptions`).
    design : dataclass or dict, optional
        Electrode design overrides.
    """
    def plain(x):
        return None if x is None else (asdict(x) if hasattr(x, "__dataclass_fields__") else x)

    doc = json.dumps([geometry_id, int(channel), electrode_id, plain(settings), plain(design)],
                     sort_keys=True, default=str)
    return hashlib.sha256(doc.encode()).hexdigest()


@dataclass
class StoredPlan:
    """A plan as stored: what the bridge needs for every kind, and the rest in ``meta``/``arrays``.

    Attributes
    ----------
    plan_id, geometry_id, electrode_id, method : str
    kind : str
        "channel" (an EDM feed plan) or "roughing" (a plunge-roughing plan).
    channel : int
    axis_names : tuple of str
    samples : (N, k) float
        Untimed axis values in feed order [mm, rad].
    final_pose : (4, 4) float
        Reference pose of the axis values (planner convention, channel 0) [mm].
    poses : (N, 4, 4) float
        Tool/electrode frame -> W at each sample, in the plan's channel [mm].
    meta : dict
        JSON-safe rest (message, metrics, settings, ...).
    arrays : dict of str -> ndarray
        Further arrays (nodes, electrode mesh, ...).
    created, version : str
    """

    plan_id: str
    kind: str
    geometry_id: str
    channel: int
    electrode_id: str
    method: str
    axis_names: tuple
    samples: np.ndarray
    final_pose: np.ndarray
    poses: np.ndarray
    meta: dict = field(default_factory=dict)
    arrays: dict = field(default_factory=dict)
    created: str = ""
    version: str = __version__


def _pack(stored):
    arrays = dict(stored.arrays, samples=stored.samples, final_pose=stored.final_pose, poses=stored.poses)
    buf = io.BytesIO()
    np.savez(buf, **{k: np.asarray(v) for k, v in arrays.items()})
    head = {"plan_id": stored.plan_id, "kind": stored.kind, "geometry_id": stored.geometry_id,
            "channel": int(stored.channel), "electrode_id": stored.electrode_id, "method": stored.method,
            "axis_names": list(stored.axis_names), "meta": stored.meta, "created": stored.created,
            "version": stored.version}
    head_bytes = json.dumps(head, sort_keys=True, allow_nan=True).encode()
    raw = len(head_bytes).to_bytes(8, "little") + head_bytes + buf.getvalue()
    return zlib.compress(raw, 6)


def _unpack(blob):
    raw = zlib.decompress(blob)
    n = int.from_bytes(raw[:8], "little")
    head = json.loads(raw[8:8 + n].decode())
    with np.load(io.BytesIO(raw[8 + n:]), allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    return StoredPlan(plan_id=head["plan_id"], kind=head["kind"], geometry_id=head["geometry_id"],
                      channel=int(head["channel"]), electrode_id=head["electrode_id"], method=head["method"],
                      axis_names=tuple(head["axis_names"]), samples=arrays.pop("samples"),
                      final_pose=arrays.pop("final_pose"), poses=arrays.pop("poses"), meta=head["meta"],
                      arrays=arrays, created=head["created"], version=head["version"])


class PlanStore:
    """The plans of one directory (``<directory>/plans.sqlite``, created on first use).

    Parameters
    ----------
    directory : path
        Created if missing.

    Raises
    ------
    PlanStoreError
        The directory cannot be created, or the file is not a plan store of this
        schema or fails SQLite's integrity check. The file is not touched.
    """

    def __init__(self, directory):
        self.directory = pathlib.Path(directory).expanduser()
        self.path = self.directory / FILE_NAME
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise PlanStoreError(f"plan store directory {self.directory}: {exc}") from None
        self._check_or_create()

    def __repr__(self):
        return f"PlanStore({str(self.directory)!r})"

    # -- the file ---------------------------------------------------------------------------
    def _connect(self):
        try:
            con = sqlite3.connect(self.path, timeout=30.0, isolation_level=None)
        except sqlite3.Error as exc:
            raise PlanStoreError(f"cannot open the plan store {self.path}: {exc}") from None
        return con

    def _refuse(self, why):
        raise PlanStoreError(f"{self.path} {why}; it was left untouched: move it away or point the plan "
                             f"store to another directory")

    def _check_or_create(self):
        con = self._connect()
        try:
            # new, or still empty: another process may have created the file and not yet its tables (the
            # planner and the bridge start together on a new machine); the creation below is serialised
            # by BEGIN IMMEDIATE and skipped by whoever comes second
            fresh = (not con.execute("SELECT name FROM sqlite_master").fetchall()
                     and con.execute("PRAGMA application_id").fetchone()[0] in (0, APPLICATION_ID))
            if fresh:
                con.execute("PRAGMA journal_mode=WAL")
                con.execute(f"PRAGMA application_id={APPLICATION_ID}")
                con.execute("BEGIN IMMEDIATE")
                if not con.execute("SELECT name FROM sqlite_master").fetchall():   # nobody was faster
                    for statement in filter(str.strip, _SCHEMA_SQL.split(";")):
                        con.execute(statement)
                    con.executemany("INSERT INTO meta VALUES (?, ?)",
                                    [("application", APPLICATION), ("schema", str(SCHEMA)),
                                     ("created_by", f"edm_planner {__version__}")])
                con.execute("COMMIT")
            self._validate(con)
            if not con.execute("SELECT name FROM sqlite_master WHERE type='table' AND name='sequences'").fetchall():
                con.execute("BEGIN IMMEDIATE")
                con.execute(_SEQUENCES_SQL)          # IF NOT EXISTS: another process may have been faster
                con.execute("COMMIT")
        except sqlite3.DatabaseError as exc:
            if _not_the_file(exc):         # a full disk, no permission, locked: the file itself may be fine
                raise PlanStoreError(f"cannot open the plan store {self.path}: {exc}"
                                     f"{_disk_note(exc, self.directory)}; the file was not changed") from None
            self._refuse(f"is not a usable SQLite database ({exc})")
        finally:
            con.close()

    def _validate(self, con):
        tables = {r[0] for r in con.execute("SELECT name FROM sqlite_master WHERE type='table'")}
        if "meta" not in tables:
            self._refuse(f"is an SQLite database of another application (tables: {sorted(tables) or 'none'})")
        meta = dict(con.execute("SELECT key, value FROM meta").fetchall())
        if meta.get("application") != APPLICATION:
            self._refuse(f"is an SQLite database of another application (application "
                         f"{meta.get('application')!r})")
        if meta.get("schema") != str(SCHEMA):
            self._refuse(f"has plan store schema {meta.get('schema')!r}; this edm_planner {__version__} reads "
                         f"schema {SCHEMA}")
        if "plans" not in tables:
            self._refuse("has no plans table")
        check = con.execute("PRAGMA quick_check").fetchall()
        if check != [("ok",)]:
            self._refuse(f"fails SQLite's integrity check: {'; '.join(str(r[0]) for r in check[:3])}")

    # -- records ----------------------------------------------------------------------------
    def put(self, stored, key=None):
        """Store a plan (replacing a record of the same plan id) under its id and ``key``.

        Raises
        ------
        PlanStoreError
            The write failed; nothing was changed.
        """
        stored.created = stored.created or datetime.datetime.now(datetime.timezone.utc).isoformat(
            timespec="seconds")
        blob = _pack(stored)
        row = (stored.plan_id, key, stored.kind, stored.geometry_id, int(stored.channel), stored.electrode_id,
               stored.method, stored.created, stored.version, hashlib.sha256(blob).hexdigest(), blob)
        con = self._connect()
        try:
            with con:
                con.execute("BEGIN IMMEDIATE")
                con.execute("INSERT OR REPLACE INTO plans VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)", row)
        except sqlite3.Error as exc:
            raise PlanStoreError(f"cannot store plan {stored.plan_id} in {self.path}: {exc}"
                                 f"{_disk_note(exc, self.directory)}; nothing was changed") from None
        finally:
            con.close()
        log.info("stored plan %s in %s", stored.plan_id, self.path)

    def _fetch_one(self, sql, params):
        """One row of a read (or None); an unreadable store is a PlanStoreError."""
        con = self._connect()
        try:
            return con.execute(sql, params).fetchone()
        except sqlite3.Error as exc:
            raise PlanStoreError(f"cannot read the plan store {self.path}: {exc}") from None
        finally:
            con.close()

    def _one(self, where, value):
        row = self._fetch_one(f"SELECT plan_id, sha256, record FROM plans WHERE {where} = ? "
                              f"ORDER BY created DESC LIMIT 1", (value,))
        if row is None:
            return None
        plan_id, digest, blob = row
        if not isinstance(blob, bytes) or hashlib.sha256(blob).hexdigest() != digest:
            raise PlanStoreError(f"plan {plan_id} in {self.path} is corrupt (its checksum does not match); the "
                                 f"record was left as it is")
        try:
            stored = _unpack(blob)
        except Exception as exc:  # a record we wrote and checksummed but cannot read: say which
            raise PlanStoreError(f"plan {plan_id} in {self.path} cannot be read: {exc!r}") from None
        if stored.plan_id != plan_id:
            raise PlanStoreError(f"plan {plan_id} in {self.path} holds plan {stored.plan_id}: the store is "
                                 f"inconsistent")
        return stored

    def get(self, plan_id):
        """The stored plan of ``plan_id``, or None."""
        return self._one("plan_id", plan_id)

    def find(self, key):
        """The plan stored for request ``key``, or None."""
        return self._one("request_key", key)

    def list(self, limit=None):
        """Summary rows (plan_id, kind, geometry_id, channel, electrode_id, method, created), newest first."""
        con = self._connect()
        try:
            sql = ("SELECT plan_id, kind, geometry_id, channel, electrode_id, method, created FROM plans "
                   "ORDER BY created DESC")
            rows = con.execute(sql + (f" LIMIT {int(limit)}" if limit else "")).fetchall()
        except sqlite3.Error as exc:
            raise PlanStoreError(f"cannot read the plan store {self.path}: {exc}") from None
        finally:
            con.close()
        keys = ("plan_id", "kind", "geometry_id", "channel", "electrode_id", "method", "created")
        return [dict(zip(keys, r)) for r in rows]


    # -- sequences ------------------------------------------------------------------------------
    def put_sequence(self, sequence_id, kind, steps, meta=None):
        """Store a sequence of (plan id, channel) steps (replacing one of the same id).

        Parameters
        ----------
        sequence_id : str
        kind : str
            "electrode_set" (the set's electrodes in machining order, one channel) or "blisk_program"
            (each electrode through every channel, then the next).
        steps : sequence of (plan_id, channel)
            Every plan id must be a channel plan of this store, all of one geometry.
        meta : dict, optional
            JSON-safe rest (labels, removal figures, ...). A blisk program's ``blade_count`` (N, whose pitch
            2 pi / N its index turns use) is taken from a complete program's steps when not given, and must be
            given for a partial one.

        Returns
        -------
        StoredSequence

        Raises
        ------
        EdmError
            INVALID_REQUEST (unknown kind, empty or malformed steps, plans of several geometries), UNKNOWN_ID
            (a step names a plan not in the store); PlanStoreError when the write fails (nothing changed).
        """
        if kind not in SEQUENCE_KINDS:
            raise EdmError(ErrorCode.INVALID_REQUEST, f"sequence kind {kind!r} is none of {list(SEQUENCE_KINDS)}")
        if not isinstance(sequence_id, str) or not sequence_id.strip():
            raise EdmError(ErrorCode.INVALID_REQUEST, "a sequence needs a non-empty id")
        try:
            steps = [(str(p), int(c)) for p, c in steps]
        except (TypeError, ValueError):
            raise EdmError(ErrorCode.INVALID_REQUEST, f"sequence {sequence_id}: steps must be (plan id, channel) "
                                                      f"pairs") from None
        if not steps or any(c < 0 for _, c in steps):
            raise EdmError(ErrorCode.INVALID_REQUEST, f"sequence {sequence_id}: needs at least one step, channels "
                                                      f">= 0")
        meta = dict(meta or {})
        if kind == "blisk_program":
            meta["blade_count"] = _program_blade_count(sequence_id, steps, meta.get("blade_count"))
        geometries = set()
        for plan_id in dict.fromkeys(p for p, _ in steps):
            stored = self.get(plan_id)
            if stored is None:
                raise EdmError(ErrorCode.UNKNOWN_ID, f"sequence {sequence_id}: plan {plan_id} is not in the plan "
                                                     f"store {self.path}")
            if stored.kind != "channel":
                raise EdmError(ErrorCode.INVALID_REQUEST, f"sequence {sequence_id}: plan {plan_id} is a "
                                                          f"{stored.kind} plan, not a channel plan")
            geometries.add(stored.geometry_id)
        if len(geometries) > 1:
            raise EdmError(ErrorCode.INVALID_REQUEST, f"sequence {sequence_id}: its plans belong to "
                                                      f"{len(geometries)} geometries")
        seq = StoredSequence(sequence_id=sequence_id, kind=kind, geometry_id=geometries.pop(), steps=steps,
                             meta=meta,
                             created=datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"))
        head = {"sequence_id": seq.sequence_id, "kind": kind, "geometry_id": seq.geometry_id,
                "steps": [list(s) for s in steps], "meta": seq.meta, "created": seq.created, "version": seq.version}
        blob = zlib.compress(json.dumps(head, sort_keys=True, allow_nan=True).encode(), 6)
        con = self._connect()
        try:
            with con:
                con.execute("BEGIN IMMEDIATE")
                con.execute("INSERT OR REPLACE INTO sequences VALUES (?, ?, ?, ?, ?, ?, ?)",
                            (sequence_id, kind, seq.geometry_id, seq.created, seq.version,
                             hashlib.sha256(blob).hexdigest(), blob))
        except sqlite3.Error as exc:
            raise PlanStoreError(f"cannot store sequence {sequence_id} in {self.path}: {exc}") from None
        finally:
            con.close()
        log.info("stored %s %s (%d steps) in %s", kind, sequence_id, len(steps), self.path)
        return seq

    def get_sequence(self, sequence_id):
        """The :class:`StoredSequence` of ``sequence_id``, or None."""
        row = self._fetch_one("SELECT sha256, record FROM sequences WHERE sequence_id = ?", (sequence_id,))
        if row is None:
            return None
        digest, blob = row
        if not isinstance(blob, bytes) or hashlib.sha256(blob).hexdigest() != digest:
            raise PlanStoreError(f"sequence {sequence_id} in {self.path} is corrupt (its checksum does not match); "
                                 f"the record was left as it is")
        try:
            head = json.loads(zlib.decompress(blob).decode())
            seq = StoredSequence(sequence_id=head["sequence_id"], kind=head["kind"], geometry_id=head["geometry_id"],
                                 steps=[(str(p), int(c)) for p, c in head["steps"]], meta=head["meta"],
                                 created=head["created"], version=head["version"])
        except Exception as exc:  # checksummed but unreadable: say which
            raise PlanStoreError(f"sequence {sequence_id} in {self.path} cannot be read: {exc!r}") from None
        if seq.sequence_id != sequence_id:
            raise PlanStoreError(f"sequence {sequence_id} in {self.path} holds {seq.sequence_id}: the store is "
                                 f"inconsistent")
        return seq

    def list_sequences(self, limit=None):
        """Summary rows (sequence_id, kind, geometry_id, created), newest first."""
        con = self._connect()
        try:
            sql = "SELECT sequence_id, kind, geometry_id, created FROM sequences ORDER BY created DESC"
            rows = con.execute(sql + (f" LIMIT {int(limit)}" if limit else "")).fetchall()
        except sqlite3.Error as exc:
            raise PlanStoreError(f"cannot read the plan store {self.path}: {exc}") from None
        finally:
            con.close()
        return [dict(zip(("sequence_id", "kind", "geometry_id", "created"), r)) for r in rows]


def _program_blade_count(sequence_id, steps, given):
    """The blade count N of a blisk program: as given (every channel below it), or of a complete program.

    A program's index turns are (k - k') 2 pi / N: a wrong N would index to the wrong place, so N is never
    guessed from a partial program.
    """
    channels = [c for _, c in steps]
    if given is not None:
        if isinstance(given, bool) or not isinstance(given, int) or given < 1 or max(channels) >= given:
            raise EdmError(ErrorCode.INVALID_REQUEST, f"blisk program {sequence_id}: blade_count {given!r} must be "
                                                      f"an integer above every channel (largest {max(channels)})")
        return given
    runs, last = [], None
    for plan_id, c in steps:
        if plan_id != last:
            runs.append([])
            last = plan_id
        runs[-1].append(c)
    n = len(runs[0])
    if any(r != list(range(n)) for r in runs):
        raise EdmError(ErrorCode.INVALID_REQUEST, f"blisk program {sequence_id}: each electrode must run through "
                                                  f"channels 0 .. N-1 in order (blisk_program_steps), or the meta must "
                                                  f"give blade_count")
    return n


@dataclass
class StoredSequence:
    """An ordered list of (plan id, channel) steps: an electrode set or a whole-blisk program.

    Attributes
    ----------
    sequence_id, kind, geometry_id : str
    steps : list of (str, int)
        (plan id, channel) in machining order.
    meta : dict
        JSON-safe rest (e.g. ``blade_count``, ``labels``).
    created, version : str
    """

    sequence_id: str
    kind: str
    geometry_id: str
    steps: list
    meta: dict = field(default_factory=dict)
    created: str = ""
    version: str = __version__

    @property
    def plan_ids(self):
        """The distinct plan ids in machining order (one per electrode)."""
        return list(dict.fromkeys(p for p, _ in self.steps))


def default_store_dir():
    """``$EDM_PLANNER_PLAN_STORE``, else ``~/.local/share/edm_planner/plan_store``."""
    return os.environ.get(ENV_VAR) or os.path.join(os.path.expanduser("~"), ".local", "share", "edm_planner",
                                                   "plan_store")


def open_store(directory):
    """A :class:`PlanStore` of ``directory`` ('' -> :func:`default_store_dir`), or None for ``"none"``."""
    if directory == "none":
        return None
    return PlanStore(directory or default_store_dir())


# -- channel plans ----------------------------------------------------------------------------

def plan_to_stored(plan):
    """A certified :class:`~edm_planner.planning.plan.Plan` as a record (kind "channel"), with its certificate digest.

    The digest (:mod:`~edm_planner.records.certificate`, ``meta["certificate_sha256"]``) is of the plan as it is
    here, right after planning and certification, or as it was verified when read (:func:`stored_to_plan`).
    """
    mesh = plan.electrode_mesh
    cycle_meta, cycle_arrays = cycle_to_record(getattr(plan, "cycle", None))
    return _sealed(StoredPlan(
        plan_id=plan.plan_id, kind="channel", geometry_id=plan.geometry_id, channel=int(plan.channel),
        electrode_id=plan.electrode_id, method=plan.options.search.method, axis_names=tuple(plan.axis_names),
        samples=np.asarray(plan.samples, dtype=np.float64), final_pose=np.asarray(plan.final_pose, np.float64),
        poses=np.asarray(plan.poses, dtype=np.float64),
        meta={"error_code": int(plan.error_code), "message": plan.message, "options": asdict(plan.options),
              "metrics": plan.metrics.to_dict(), "removal": getattr(plan, "removal", None),
              "set_id": getattr(plan, "set_id", "") or "", **cycle_meta},
        arrays={"nodes": np.asarray(plan.nodes, dtype=np.float64),
                "electrode_vertices": np.asarray(mesh.vertices, dtype=np.float64),
                "electrode_faces": np.asarray(mesh.faces, dtype=np.int64), **cycle_arrays}))


def _sealed(stored):
    """The record with its certificate digest in ``meta`` (computed from the record itself)."""
    stored.meta[META_KEY] = record_digest(stored)
    return stored


def stored_to_plan(stored, where="the plan store"):
    """The :class:`~edm_planner.planning.plan.Plan` of a "channel" record, arrays bit for bit.

    Raises
    ------
    NotCertifiedError
        NOT_CERTIFIED: the record has no certificate digest or does not match it (altered after certification).
    """
    if stored.kind != "channel":
        raise PlanStoreError(f"plan {stored.plan_id} is a {stored.kind} plan, not a channel plan")
    verify_record(stored, where)
    options = plan_options_from_dict(stored.meta["options"])
    metrics = PlanMetrics.from_dict(stored.meta["metrics"])
    mesh = trimesh.Trimesh(stored.arrays["electrode_vertices"], stored.arrays["electrode_faces"], process=False)
    return Plan(plan_id=stored.plan_id, error_code=ErrorCode(stored.meta["error_code"]),
                message=stored.meta["message"], geometry_id=stored.geometry_id, channel=stored.channel,
                electrode_id=stored.electrode_id, electrode_mesh=mesh, final_pose=stored.final_pose,
                options=options, axis_names=stored.axis_names,
                samples=stored.samples, poses=stored.poses, nodes=stored.arrays["nodes"],
                metrics=metrics, cycle=cycle_from_record(stored.meta, stored.arrays),
                removal=stored.meta.get("removal"), set_id=stored.meta.get("set_id", ""))


def plan_cycle_of_stored(stored, where="the plan store"):
    """The :class:`~edm_planner.machining.program.PlanCycle` of a record (any kind; only channel plans carry a
    cycle), its certificate digest verified.

    Raises
    ------
    NotCertifiedError
        NOT_CERTIFIED for a record without a digest or not matching it: nothing is run that was not certified.
    """
    verify_record(stored, where)
    cycle = cycle_from_record(stored.meta, stored.arrays) if stored.kind == "channel" else None
    return PlanCycle(stored.plan_id, stored.geometry_id, stored.electrode_id, int(stored.channel),
                     tuple(stored.axis_names), np.asarray(stored.final_pose, dtype=np.float64),
                     np.asarray(stored.samples, dtype=np.float64), cycle)


# -- roughing plans ---------------------------------------------------------------------------

def roughing_to_stored(result, plan_id, geometry_id):
    """A :class:`~edm_planner.roughing.RoughingResult` as a record (kind "roughing").

    Per-position arrays are kept in travel order; the dense poses are the tool frames along the path.
    """
    order = np.asarray(result.order)
    meta = {"labels": [result.labels[i] for i in order], "tool_radius": result.tool_radius,
            "l_min": result.l_min, "r_max": result.r_max, "line_count": int(result.line_count),
            "stats_initial": result.stats_initial.to_dict(), "stats": result.stats.to_dict(),
            "mae_reduction_percent": result.mae_reduction_percent, "planning_time": result.planning_time,
            "options": result.options.to_dict(),
            "message": (f"{result.position_count} plunge positions ({result.groove_count} grooving, "
                        f"{result.line_count} expansion lines), tool radius {result.tool_radius:.4f} mm: mean "
                        f"absolute error {result.stats_initial.mean_abs:.5f} -> {result.stats.mean_abs:.5f} mm "
                        f"({result.mae_reduction_percent:.2f} % less; the paper: 57.79 %)")}
    return _sealed(StoredPlan(
        plan_id=plan_id, kind="roughing", geometry_id=geometry_id, channel=int(result.channel), electrode_id="tool",
        method="plunge_roughing", axis_names=tuple(result.axis_names),
        samples=np.asarray(result.samples, dtype=np.float64),
        final_pose=np.asarray(result.reference_pose, dtype=np.float64),
        poses=np.asarray(result.path.tool_poses(), dtype=np.float64), meta=meta,
        arrays={"tool_poses": np.asarray(result.poses, dtype=np.float64)[order],
                "initial_tool_poses": np.asarray(result.initial_poses, dtype=np.float64)[order],
                "hausdorff_initial": np.asarray(result.hausdorff_initial, dtype=np.float64)[order],
                "hausdorff": np.asarray(result.hausdorff, dtype=np.float64)[order],
                "bottom_index": np.asarray(result.bottom_index, dtype=np.int64)}))
