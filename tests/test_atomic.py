"""Atomic files (hfdi.files), used by the validation tools, the benchmarks and
the FMU build: the program's own files, and the outputs the user names
(through symbolic links, into FIFOs and devices, never replacing them)."""
import errno
import json
import os
import select
import socket
import stat
import threading
import zipfile
from pathlib import Path

import pytest

from hfdi.files import atomic_file, write_atomic


def test_written_file_has_the_usual_permissions(tmp_path):
    mask = os.umask(0o022)
    try:
        path = write_atomic(tmp_path / "a" / "out.txt", "hello")
    finally:
        os.umask(mask)
    assert path.read_text() == "hello"
    assert stat.S_IMODE(path.stat().st_mode) == 0o644


def test_failure_keeps_the_old_file_and_leaves_no_temporary(tmp_path):
    path = tmp_path / "out.bin"
    write_atomic(path, b"old")
    with pytest.raises(RuntimeError):
        with atomic_file(path) as fh:
            fh.write(b"half of the new")
            raise RuntimeError("killed")
    assert path.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["out.bin"]


# -- outputs the user named (hfdi.files.write_output) -------------------------------------
def drain(fd, chunks, timeout=10.0):
    """Read the FIFO ``fd`` (opened for reading) until its writer closes it."""
    poller = select.poll()
    poller.register(fd, select.POLLIN)
    while poller.poll(timeout * 1000):
        chunk = os.read(fd, 65536)
        if not chunk:
            break
        chunks.append(chunk)


class FifoReader:
    """A reader of the FIFO ``path`` in a thread, there before any writer."""

    def __init__(self, path):
        self.fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
        self.chunks = []
        self.thread = threading.Thread(target=drain, args=(self.fd, self.chunks))
        self.thread.start()

    def data(self) -> bytes:
        self.thread.join(30)
        os.close(self.fd)
        return b"".join(self.chunks)


def test_an_output_through_a_symbolic_link_replaces_its_target(tmp_path):
    """The link stays and points where it did; the file it points to is
    replaced atomically, in its own directory, keeping its permissions; a
    dangling link's target is made."""
    from hfdi.files import write_output
    results = tmp_path / "results"
    results.mkdir()
    real = results / "real.json"
    real.write_text("old")
    real.chmod(0o640)
    link = tmp_path / "out.json"
    link.symlink_to(Path("results") / "real.json")
    write_output(link, "new")
    assert link.is_symlink() and os.readlink(link) == str(Path("results") / "real.json")
    assert real.read_text() == "new" and stat.S_IMODE(real.stat().st_mode) == 0o640
    dangling = tmp_path / "dangling.json"
    dangling.symlink_to(results / "made.json")
    write_output(dangling, b"made")
    assert dangling.is_symlink() and (results / "made.json").read_bytes() == b"made"
    assert sorted(p.name for p in results.iterdir()) == ["made.json", "real.json"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dangling.json", "out.json",
                                                         "results"]


def test_an_output_into_a_fifo(tmp_path):
    """A FIFO with a reader gets the whole output and stays a FIFO; one
    without a reader is refused at once (no wait), nothing replaced; an
    output that fails while it is made writes nothing into it."""
    from hfdi.files import atomic_output, write_output
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    reader = FifoReader(fifo)
    write_output(fifo, b"x" * 300_000)              # more than a pipe holds
    assert reader.data() == b"x" * 300_000
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
    with pytest.raises(OSError, match="no reader"):
        write_output(fifo, "nobody reads")
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
    reader = FifoReader(fifo)
    with pytest.raises(RuntimeError):
        with atomic_output(fifo) as fh:
            fh.write(b"half")
            raise RuntimeError("killed")
    os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))      # the reader's end of file
    assert reader.data() == b""
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pipe"]


@pytest.mark.parametrize("device, minor", [("null", 3), ("full", 7)])
def test_an_output_to_a_character_device_is_written_not_replaced(tmp_path, device, minor):
    """A device node (a private copy of /dev/null or /dev/full, made where
    this process may make one) is written to: /dev/null takes the output,
    /dev/full refuses it with OSError (ENOSPC); the node stays a device."""
    from hfdi.files import write_output
    node = tmp_path / device
    try:
        os.mknod(node, stat.S_IFCHR | 0o666, os.makedev(1, minor))
        os.close(os.open(node, os.O_WRONLY))
    except OSError as exc:
        pytest.skip(f"no device node can be made here: {exc}")
    if device == "null":
        write_output(node, "{}")
    else:
        with pytest.raises(OSError) as info:
            write_output(node, "{}")
        assert info.value.errno == errno.ENOSPC
    assert stat.S_ISCHR(os.stat(node).st_mode)
    assert sorted(p.name for p in tmp_path.iterdir()) == [device]


def test_an_output_to_a_socket_is_refused(tmp_path):
    from hfdi.files import write_output
    path = tmp_path / "sock"
    with socket.socket(socket.AF_UNIX) as server:
        server.bind(str(path))
        with pytest.raises(OSError, match="socket"):
            write_output(path, "{}")
    assert stat.S_ISSOCK(os.stat(path).st_mode)


def test_a_failing_output_keeps_the_previous_file(tmp_path):
    from hfdi.files import atomic_output, write_output
    path = tmp_path / "out.json"
    write_output(path, "good")
    with pytest.raises(RuntimeError):
        with atomic_output(path) as fh:
            fh.write(b"half of the new")
            raise RuntimeError("disk full")
    assert path.read_text() == "good"
    assert [p.name for p in tmp_path.iterdir()] == ["out.json"]


# -- the commands' outputs ----------------------------------------------------------------
TABLE = ["table", "dumbbell", "--t-end", "0.05", "--targets", "3", "--schemes", "hfdi",
         "--no-eps"]


def table(*extra) -> int:
    from validation.cli import main
    return main([*TABLE, *extra])


def test_cli_json_through_a_symbolic_link(tmp_path, capsys):
    """``hfdi-validate table --json out.json`` with ``out.json -> results/real.json``:
    real.json gets the records, the link stays (it became a regular file)."""
    (tmp_path / "results").mkdir()
    link = tmp_path / "out.json"
    link.symlink_to(Path("results") / "real.json")
    assert table("--json", str(link)) == 0
    assert link.is_symlink()
    records = json.loads((tmp_path / "results" / "real.json").read_text())
    assert [r["scheme"] for r in records] == ["hfdi"]


def test_cli_json_into_a_fifo_with_a_reader(tmp_path, capsys):
    """The reader of a FIFO gets the records (it got 0 bytes: the FIFO was
    replaced by a file), and the FIFO stays."""
    fifo = tmp_path / "runs.json"
    os.mkfifo(fifo)
    reader = FifoReader(fifo)
    try:
        status = table("--json", str(fifo))
    finally:
        data = reader.data()
    assert status == 0
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
    assert [r["scheme"] for r in json.loads(data)] == ["hfdi"]


def test_cli_refuses_a_socket_as_output_before_the_runs(tmp_path, capsys):
    path = tmp_path / "sock"
    with socket.socket(socket.AF_UNIX) as server:
        server.bind(str(path))
        with pytest.raises(SystemExit) as info:
            table("--json", str(path))
    assert info.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "is a socket" in err[0], err
    assert stat.S_ISSOCK(os.stat(path).st_mode)


@pytest.mark.parametrize("where", ["while the rows are made", "on the disk"])
def test_cli_csv_that_fails_keeps_the_previous_file(tmp_path, capsys, monkeypatch, where):
    """``--csv`` was written in place: a write that failed half-way destroyed
    the previous, good CSV. Now it is untouched, and the command says why in
    one line (exit status 1)."""
    import csv
    out = tmp_path / "runs.csv"
    out.write_text("previous,good\n")

    def disk_full(*args):
        raise OSError(errno.ENOSPC, "No space left on device")

    if where == "on the disk":
        monkeypatch.setattr(os, "fsync", disk_full)
    else:
        make = csv.writer

        class Failing:
            def __init__(self, fh, **kwargs):
                self.writer, self.rows = make(fh, **kwargs), 0

            def writerow(self, row):
                self.rows += 1
                if self.rows > 1:
                    disk_full()
                self.writer.writerow(row)

        monkeypatch.setattr(csv, "writer", Failing)
    assert table("--csv", str(out)) == 1
    assert out.read_text() == "previous,good\n"
    err = capsys.readouterr().err.strip().splitlines()
    assert "No space left on device" in err[-1] and err[-1].startswith("hfdi-validate: error")
    assert [p.name for p in tmp_path.iterdir()] == ["runs.csv"]


@pytest.mark.slow
def test_hfdi_fmu_build_through_a_symbolic_link(tmp_path, capsys):
    """``hfdi-fmu build`` into ``--out`` where the FMU's name is a link: the
    FMU is written where the link points, the link stays."""
    pytest.importorskip("pythonfmu")
    pytest.importorskip("fmpy")
    from fmu.cli import main
    (tmp_path / "fmus").mkdir()
    out = tmp_path / "out"
    out.mkdir()
    link = out / "hfdi_dumbbell.fmu"
    link.symlink_to(tmp_path / "fmus" / "dumbbell-v2.fmu")
    assert main(["build", "dumbbell", "--out", str(out)]) == 0
    assert link.is_symlink()
    with zipfile.ZipFile(tmp_path / "fmus" / "dumbbell-v2.fmu") as archive:
        assert "modelDescription.xml" in archive.namelist()
