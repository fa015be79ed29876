"""Faults of the plan store and the field cache (issue 15): writers killed mid-write, a full disk.

The writers are separate processes (``store_writer``, below) writing records of known content, so that
every record that was reported stored can be compared bit for bit afterwards.
"""

import contextlib
import os
import pathlib
import shutil
import signal
import sqlite3
import subprocess
import sys
import time

import numpy as np

from edm_planner.records.store import FILE_NAME, PlanStore

from test_faults_records import record, store_rows

#: a process that writes records ``first`` .. ``first + count - 1`` (content from the index) to a store,
#: printing "put i" before and "ok i" after each, or "error i <message>" and exit 1; optionally under a
#: file-size limit (RLIMIT_FSIZE, bytes); or, with "field", builds a coarse distance field with a cache
WRITER = r"""
import logging, resource, sys, time
logging.basicConfig(level=logging.INFO, format="%(levelname)s %(message)s")
mode, directory, first, count, fsize = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), int(sys.argv[5])
if fsize:
    resource.setrlimit(resource.RLIMIT_FSIZE, (fsize, fsize))
sys.path.insert(0, sys.argv[6])
from test_faults_records import record
if mode == "field":
    from edm_planner.geometry.loader import load_geometry
    from edm_planner.interference.fast import FastChannelField
    g = load_geometry(sys.argv[7])
    f = FastChannelField(g.blisk, spacing=1.0, cache_dir=directory, cache_key=sys.argv[8])
    print("field", f.build_seconds, float(f.error_bound), flush=True)
    sys.exit(0)
from edm_planner.records.store import PlanStore, PlanStoreError
store = PlanStore(directory)
for i in range(first, first + count):
    print("put", i, flush=True)
    t = time.perf_counter()
    try:
        store.put(record(i), f"key{i}")
    except PlanStoreError as exc:
        print("error", i, exc.message, flush=True)
        sys.exit(1)
    print("ok", i, time.perf_counter() - t, flush=True)
"""

HERE = pathlib.Path(__file__).resolve().parent


def writer(mode, directory, first=0, count=1, fsize=0, *extra):
    return subprocess.Popen([sys.executable, "-c", WRITER, mode, str(directory), str(first), str(count), str(fsize),
                             str(HERE), *map(str, extra)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)


def check_records(directory, indices):
    """Every record of ``indices`` reads back from a newly opened store, bit for bit."""
    store = PlanStore(directory)
    for i in indices:
        got, want = store.find(f"key{i}"), record(i)
        assert got is not None, f"record {i} lost"
        assert got.plan_id == want.plan_id and got.meta == want.meta
        for name in ("samples", "poses", "final_pose"):
            np.testing.assert_array_equal(getattr(got, name), getattr(want, name))
        np.testing.assert_array_equal(got.arrays["nodes"], want.arrays["nodes"])


def test_writers_killed_mid_write_leave_every_stored_record_whole(tmp_path):
    ok, whole, seconds = [], 0, []
    for round_ in range(12):
        proc = writer("store", tmp_path, first=100 * round_, count=50)
        stop_after = round_ % 4                        # killed in the first .. fourth write of the round
        seen, killed = 0, None
        for line in proc.stdout:
            word, i, *rest = line.split()
            if word == "ok":
                ok.append(int(i))
                seconds.append(float(rest[0]))
            elif word == "put":
                if seen == stop_after:
                    # at a point spread over the write as this run measures it (packing, then SQLite)
                    if seconds:
                        time.sleep(float(np.median(seconds)) * (round_ % 6) / 5)
                    os.killpg(proc.pid, signal.SIGKILL)
                    break
                seen += 1
        for line in [line, *proc.stdout]:        # what it said before it died: its last "put" was the killed one
            if not line.endswith("\n"):
                continue                        # cut off by the kill
            word, i, *rest = line.split()
            if word == "ok" and int(i) not in ok:
                ok.append(int(i))
            killed = int(i) if word == "put" else killed
        assert proc.wait(timeout=60) == -signal.SIGKILL, proc.stderr.read()
        plans, _ = store_rows(tmp_path)                     # integrity check passes
        present = {int(k[3:]) for k, *_ in plans.values()}
        assert set(ok) <= present and present <= set(ok) | {killed}     # the killed record: whole or absent
        if killed in present:
            ok.append(killed)
            whole += 1
        check_records(tmp_path, ok)
    print(f"12 writers killed: the record being written was whole {whole} times, absent {12 - whole} times")
    assert len(ok) >= 18                          # each round stored its first stop_after records at least


@contextlib.contextmanager
def small_disk(path, size="8m"):
    """A small file system mounted at ``path`` (as root): "tmpfs", else "loop" (an ext2 image loop-mounted),
    else None where neither can be mounted.

    ``EDM_TEST_NO_TMPFS=1`` skips the tmpfs (the loop mount is tried), ``EDM_TEST_NO_LOOP=1`` the loop mount.
    Where neither is there, the full-disk test limits the writers' file size instead (RLIMIT_FSIZE: writes
    beyond it fail with EFBIG) and the `edm-plan plan` row fails, saying why: no row skips.
    """
    path.mkdir()
    kind = None
    if not os.environ.get("EDM_TEST_NO_TMPFS") and shutil.which("mount"):
        r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)], capture_output=True,
                           timeout=60)
        kind = "tmpfs" if r.returncode == 0 else None
    if kind is None and not os.environ.get("EDM_TEST_NO_LOOP") and shutil.which("mount") and shutil.which("mke2fs"):
        image = path.parent / f"{path.name}.ext2"
        made = subprocess.run(["mke2fs", "-q", "-F", "-t", "ext2", "-m", "0", str(image), size.upper()],
                              capture_output=True, timeout=60)
        r = made if made.returncode else subprocess.run(["mount", "-o", "loop", str(image), str(path)],
                                                        capture_output=True, timeout=60)
        if r.returncode == 0:
            kind = "loop"
            (path / "lost+found").rmdir()            # the test lists what it leaves on the disk
        else:
            print(f"no loop mount: {(r.stderr or b'').decode(errors='replace').strip()}")
    if kind is None:
        yield None
        return
    try:
        yield kind
    finally:
        subprocess.run(["umount", "-l", str(path)], check=True, timeout=60)


def fill(path):
    """Fill the file system of ``path`` with a filler file until it is full; returns the file."""
    filler = path / "filler"
    chunk = b"\0" * 4096
    with open(filler, "wb", buffering=0) as f:
        with contextlib.suppress(OSError):
            while True:
                f.write(chunk)
    return filler


def test_a_full_disk_is_a_clear_error_and_leaves_the_store_and_the_cache_whole(tmp_path):
    from edm_planner.nodes.geometry_loader import config_directory

    default = config_directory() / "default_blisk.yaml"
    with small_disk(tmp_path / "disk") as kind:
        disk = tmp_path / "disk"
        store, cache = disk / "store", disk / "cache"
        print(f"full disk: {kind or 'RLIMIT_FSIZE'}")
        proc = writer("store", store, 0, 3)
        out, err = proc.communicate(timeout=120)
        assert proc.returncode == 0, out + err
        proc = writer("field", cache, 0, 0, 0, default, "before")
        out, err = proc.communicate(timeout=300)
        assert proc.returncode == 0, out + err
        cached = sorted(p.name for p in cache.iterdir())
        assert any(n.startswith("before.") and n.endswith(".npz") for n in cached)
        before = store_rows(store)
        cache_bytes = {n: (cache / n).read_bytes() for n in cached}

        if kind:
            filler = fill(disk)
            limit = 0
        else:                 # no tmpfs: the writers' writes beyond 64 kB of a file fail (the store's index fits)
            limit = 65536
        if kind:
            # nobody else has the store open: opening it needs its shared-memory index file, which cannot be made
            proc = writer("store", store, 3, 1, limit)
            out, err = proc.communicate(timeout=120)
            assert proc.returncode == 1 and "cannot open the plan store" in err, out + err
            assert f"cannot open the plan store {store / FILE_NAME}: disk I/O error (SQLITE_IOERR" in err
            assert "free on its file system); the file was not changed" in err and "move it away" not in err
        # another process has it open (its index exists): the record's write fails, nothing is half-written
        if kind:
            filler.unlink()
        holder = sqlite3.connect(store / FILE_NAME)
        assert holder.execute("SELECT count(*) FROM plans").fetchone() == (3,)
        if kind:
            filler = fill(disk)
        try:
            proc = writer("store", store, 3, 1, limit)
            out, err = proc.communicate(timeout=120)
            assert proc.returncode == 1 and "error 3 " in out, out + err
            message = out.split("error 3 ", 1)[1]
            assert f"cannot store plan {record_id(3)} in {store / FILE_NAME}: " in message
            if kind:
                assert ("database or disk is full (SQLITE_FULL, 0.0 MB free on its file system); nothing was "
                        "changed") in message
            # still on the full disk: the store opens (its index exists) and reads as before, bit for bit
            assert store_rows(store) == before
            check_records(store, range(3))
            assert PlanStore(store).find("key3") is None
        finally:
            holder.close()
        proc = writer("field", cache, 0, 0, limit, default, "after")
        out, err = proc.communicate(timeout=300)
        assert proc.returncode == 0, out + err       # the field works from memory
        assert "cannot write the cache" in err and ("No space left on device" if kind else "File too large") in err, err
        # no half-written cache file (the build-lock file of the field stays: empty, it needs no room)
        assert sorted(p.name for p in cache.iterdir()) == sorted([*cached, "after.fast_field.s1.npz.lock"])
        assert {n: (cache / n).read_bytes() for n in cached} == cache_bytes

        if kind:
            filler.unlink()
        assert store_rows(store) == before            # room again: nothing half-written, the same write succeeds
        proc = writer("store", store, 3, 1)
        out, err = proc.communicate(timeout=120)
        assert proc.returncode == 0, out + err
        check_records(store, range(4))


def record_id(i):
    return record(i).plan_id


def test_the_cli_keeps_a_plan_the_full_store_cannot_take(tmp_path, field_cache):
    """`edm-plan plan` with its store on a full disk: the plan is planned, exported and reported, the store's
    failure is a one-line warning (exit 0), and the store is as it was."""
    from edm_planner.nodes.geometry_loader import config_directory

    with small_disk(tmp_path / "disk") as kind:
        # no skip: this row of the README's table must really run (a full disk for the store alone needs a
        # file system of its own; RLIMIT_FSIZE would also fail the plan's export)
        assert kind, ("neither a tmpfs nor a loop-mounted ext2 image can be mounted here (the tests run as root "
                      "in this repository's set-up): the full-disk row of `edm-plan plan` cannot run")
        print(f"full disk: {kind}")
        store = tmp_path / "disk" / "store"
        PlanStore(store)                                     # makes the file (nothing in it)
        holder = sqlite3.connect(store / FILE_NAME)          # its index file exists: the store opens when full
        assert holder.execute("SELECT count(*) FROM plans").fetchone() == (0,), "the new store is empty"
        filler = fill(tmp_path / "disk")
        out = tmp_path / "plan"
        try:
            proc = subprocess.run(
                [sys.executable, "-m", "edm_planner.cli", "plan", "--geometry",
                 str(config_directory() / "default_blisk.yaml"), "--channel", "0", "--out", str(out),
                 "--electrode", "rear", "--split", "front_rear", "--circumferential-reduction", "0.03",
                 "--radial-reduction", "3", "--split-overlap", "1", "--exit-side", "downstream",
                 "--store", str(store), "--cache-dir", str(field_cache), "--progress", "none"],
                capture_output=True, text=True, timeout=600)
            assert proc.returncode == 0, f"a plan whose store write fails still exits 0: {proc.stdout + proc.stderr}"
            warning = [ln for ln in proc.stderr.splitlines() if ln.startswith("warning:")]
            assert len(warning) == 1 and f"the plan is written to {out}" in warning[0], proc.stderr
            assert "not kept in the plan store: cannot store plan" in warning[0], warning[0]
            assert "database or disk is full" in warning[0], f"the warning says the disk is full: {warning[0]}"
            assert "NOT kept in the plan store" in proc.stdout, f"the summary says the plan is not kept: {proc.stdout}"
            assert (out / "plan.json").is_file(), "the plan is exported although the store could not take it"
            assert holder.execute("SELECT count(*) FROM plans").fetchone() == (0,), "the full store is as it was"
        finally:
            filler.unlink()
            holder.close()
