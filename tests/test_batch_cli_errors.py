"""Every error path of ``stereodepth batch`` that the user can reach from the command line:
one line on stderr, ``stereodepth batch: error: ...`` in the user's terms (the flag they typed,
never our classes), exit status 2, no traceback, and nothing written."""

from __future__ import annotations

import json
import os
import socket
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest

from stereodepth import _validate as check
from stereodepth import cli
from stereodepth.batch import runners

Image = pytest.importorskip("PIL.Image")


def scene(root: Path) -> Path:
    """One Middlebury scene (im0, im1, calib.txt with ndisp) in ``root/in/teddy``."""
    d = root / "in" / "teddy"
    d.mkdir(parents=True)
    rng = np.random.default_rng(0)
    left = rng.integers(0, 256, (24, 40), dtype=np.uint8)
    Image.fromarray(left).save(d / "im0.png")
    Image.fromarray(np.roll(left, -2, axis=1)).save(d / "im1.png")
    (d / "calib.txt").write_text(
        "cam0=[700 0 20; 0 700 12; 0 0 1]\ncam1=[700 0 20; 0 700 12; 0 0 1]\n"
        "doffs=0\nbaseline=100\nwidth=40\nheight=24\nndisp=16\n"
    )
    return root / "in"


# (arguments after INPUT; {tmp} is the test's folder), a fragment the message must hold
ROWS: list[tuple[list[str], str]] = [
    # matcher options: the flag or --option KEY the user typed, never BlockMatchOptions
    (
        ["--option", "foo=1"],
        "--option foo: --method bm (block matching) has no option 'foo' (its options: ",
    ),
    (["--option", "uniqueness_ratio=-1"], "--option uniqueness_ratio: uniqueness_ratio must be"),
    (["--option", "subpixel=maybe"], "--option subpixel: subpixel must be True, False"),
    (["--option", "threads=2"], "--option threads: use --threads"),
    (["--option", "channel_order=bgr"], "--option channel_order: use --channel-order"),
    (["--option", "isa=avx2"], "--option isa: not available in batch"),
    (["--option", "return_confidence=true"], "--option return_confidence: not available"),
    (["--option", "num_disparities=4"], "--option num_disparities: use --num-disparities"),
    (["--option", "foo"], "argument --option: expected KEY=VALUE with KEY a name, got 'foo'"),
    (  # the same option twice: the last one was used without a word
        ["--option", "subpixel=true", "--option", "subpixel=false"],
        "--option subpixel is given twice (True and False): give it once",
    ),
    (["--block-size", "4"], "--block-size 4: block_size must be an odd integer in [3, 63]"),
    (["--cost", "sad", "--block-size", "41"], "--block-size 41: block_size must be an odd"),
    (["--min-disparity", "99999"], "--min-disparity 99999: min_disparity must be an integer"),
    # a search range no pixel of the 40 px wide pair can match (on either side): every pair
    # failed after it was read, its records written, exit 1, without naming the flag
    (
        ["--min-disparity", "40"],
        "--min-disparity 40: pair 'teddy' would search disparities 40 to 55, none of which lies "
        "inside its 40x24 px images: only -39 to 39 can be matched along their longer side",
    ),
    (["--min-disparity", "-55"], "pair 'teddy' would search disparities -55 to -40, none of"),
    (["--num-disparities", "0"], "--num-disparities must be an integer >= 1, got 0"),
    (["--num-disparities", "5000"], "--num-disparities 5000: num_disparities must be"),
    (
        ["--num-disparities", "256", "--min-disparity", "1", "--format", "png16"],
        "--format png16 holds disparities up to 255.996 px, and teddy searches up to 256 px",
    ),
    (
        ["--min-disparity", "-8", "--format", "png16"],
        "--format png16 holds no negative disparities (KITTI's d x 256, 0 for none), and "
        "--min-disparity -8 searches them",
    ),
    # depths, calibration, runner
    (["--min-depth-m", "5", "--max-depth-m", "1"], "--max-depth-m must be >= --min-depth-m"),
    (["--max-depth-m", "0"], "--max-depth-m must be a finite number > 0, got 0.0"),
    (["--min-depth-m", "-1"], "--min-depth-m must be a finite number >= 0, got -1.0"),
    (["--focal-px", "700"], "give both --focal-px and --baseline-mm"),
    (["--focal-px", "nan", "--baseline-mm", "100"], "--focal-px must be a finite number > 0"),
    (["--cx-px", "3"], "--cx-px goes with --focal-px and --baseline-mm"),
    # a rig whose depths float32 cannot hold: refused in the flags' names before any pair
    # (each pair failed after matching, with the library's message about float64 input)
    (
        ["--focal-px", "1e30", "--baseline-mm", "1e30"],
        "--focal-px 1e+30 times --baseline-mm 1e+30 is 1e+57 px*m, outside the range",
    ),
    (
        ["--focal-px", "1e-30", "--baseline-mm", "1e-20"],
        "--focal-px 1e-30 times --baseline-mm 1e-20 is 1e-53 px*m, outside the range",
    ),
    (
        ["--focal-px", "700", "--baseline-mm", "100", "--doffs-px", "1e40"],
        "--doffs-px 1e+40 px is outside float32's range",
    ),
    (["--calib", "{tmp}/nowhere.txt"], "--calib: calibration file not found"),
    (["--workers", "0"], "--workers must be an integer >= 1, got 0"),
    (["--threads", "-1"], "--threads must be an integer >= 0"),
    # Beyond a C int it failed every pair (exit 1, the records written) with the matcher's
    # message naming threads.
    (["--threads", "2147483648"], "--threads must be an integer >= 0 and <= 2147483647"),
    (["--workers", "2", "--scheduler", "tcp://127.0.0.1:1"], "give --scheduler or --workers"),
    (["--scheduler", "foo"], "--scheduler 'foo': expected a Dask scheduler address tcp://"),
    (["--scheduler", ""], "--scheduler '': expected a Dask scheduler address tcp://HOST:PORT"),
    (["--scheduler", "http://h:8786"], "--scheduler 'http://h:8786': unknown protocol 'http'"),
    (["--scheduler", "tcp://h:0"], "--scheduler 'tcp://h:0': the port must be in 1..65535"),
    # pair names, outputs
    (["--pair-names", "cam0", "cam0"], "--pair-names: the left and right names must differ"),
    (["--pair-names", "cam", "cam1"], "--pair-names: neither name may be part of the other"),
    (["--pair-names", "cam0"], "argument --pair-names: expected 2 arguments"),
    (["--report", "{tmp}/nowhere/r.json"], "the folder '{tmp}/nowhere' does not exist"),
    (["--report", "{tmp}/out/teddy.record.json"], "pair 'teddy' writes that file"),
    (["--report", "{tmp}/in/teddy/im0.png"], "that is an input of pair 'teddy'"),
    (["--report", "{tmp}"], "--report must be a file, got the folder"),
    # argparse's own checks, in one line too
    (["--format", "tiff"], "argument --format: invalid choice: 'tiff'"),
    (["--workers", "two"], "argument --workers: invalid int value: 'two'"),
    (["--channel-order", "grb"], "argument --channel-order: invalid choice: 'grb'"),
]


def run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    try:
        status = cli.main(["batch", *argv])
    except SystemExit as exc:  # argparse exits; anything else would be a traceback
        status = int(exc.code or 0)
    return status, capsys.readouterr().err


def assert_one_line(status: int, err: str, fragment: str) -> None:
    assert status == 2, err
    assert err.count("\n") == 1 and err.endswith("\n"), err
    assert err.startswith("stereodepth batch: error: "), err
    assert fragment in err, err
    for internal in ("Traceback", "__init__", "BlockMatchOptions", "usage:"):
        assert internal not in err, err


@pytest.mark.parametrize(("extra", "fragment"), ROWS, ids=[" ".join(r[0]) for r in ROWS])
def test_batch_error_paths(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: list[str], fragment: str
) -> None:
    inp = scene(tmp_path)
    argv = [str(inp), "-o", str(tmp_path / "out"), "--quiet"]
    argv += [a.replace("{tmp}", str(tmp_path)) for a in extra]
    status, err = run(argv, capsys)
    assert_one_line(status, err, fragment.replace("{tmp}", str(tmp_path)))
    assert not (tmp_path / "out").exists()  # refused before any work


def test_input_and_output_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    inp = scene(tmp_path)
    out = str(tmp_path / "out")
    (tmp_path / "file").write_text("")
    (tmp_path / "empty").mkdir()
    (tmp_path / "bad.csv").write_text("a.png,b.png,c,d\n")
    listed = tmp_path / "list.csv"  # --report over the CSV list replaced it with the report
    listed.write_text(f"{inp}/teddy/im0.png,{inp}/teddy/im1.png,teddy\n")
    rig = str(tmp_path / "rig.txt")  # and over the job's --calib file
    fifo = tmp_path / "pipe.csv"  # a pipe was searched as a folder: "no stereo pairs found"
    os.mkfifo(fifo)
    Path(rig).write_bytes((inp / "teddy" / "calib.txt").read_bytes())
    cases = [
        ([str(tmp_path / "absent"), "-o", out], "INPUT not found"),
        ([str(tmp_path / "empty"), "-o", out], "no stereo pairs found in"),
        ([str(tmp_path / "bad.csv"), "-o", out], "bad.csv:1: expected left,right[,stem]"),
        ([str(inp), "-o", str(tmp_path / "file")], "OUTDIR must be a folder, got the file"),
        ([str(inp), "-o", str(tmp_path / "file" / "out")], "cannot be created: "),
        ([str(inp)], "the following arguments are required: -o/--output"),
        ([str(listed), "-o", out, "--report", str(listed)], f"that is INPUT {listed}"),
        ([str(inp), "-o", out, "--calib", rig, "--report", rig], f"that is --calib {rig}"),
        ([str(fifo), "-o", out], "(not a regular file: a device, pipe or socket)"),
    ]
    for argv, fragment in cases:
        status, err = run([*argv, "--quiet"], capsys)
        assert_one_line(status, err, fragment)
    assert not (tmp_path / "out").exists()


def test_an_unreachable_scheduler_leaves_none_of_the_folders_made_for_outdir(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """``-o runs/2026/out`` made runs/ and runs/2026/ too; only out/ was removed again, so the
    job that did nothing left two empty folders. A folder that was there before (empty too)
    stays."""
    distributed = pytest.importorskip("distributed")

    def refuse(address: str, **kwargs: object) -> None:
        raise OSError(f"Timed out trying to connect to {address} after 10 s")

    monkeypatch.setattr(distributed, "Client", refuse)
    monkeypatch.setattr(runners, "_handshake", lambda scheduler, timeout: None)
    inp = scene(tmp_path)
    (tmp_path / "existing").mkdir()
    out = tmp_path / "existing" / "runs" / "2026" / "out"
    argv = [str(inp), "-o", str(out), "--quiet", "--scheduler", "tcp://127.0.0.1:9"]
    status, err = run(argv, capsys)
    assert_one_line(status, err, "cannot reach the Dask scheduler")
    assert (tmp_path / "existing").is_dir()
    assert list((tmp_path / "existing").iterdir()) == []


def test_an_outdir_the_system_refuses_to_make_is_a_usage_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Under /proc (and /sys) the checks before the work pass (the parent is a writable
    folder to os.access) but making the folder fails: that was Python's "[Errno 2] ..." with
    exit status 1 and no option named."""
    target = Path("/proc/stereodepth-no-such-process/out")
    if not Path("/proc/self").is_dir():
        pytest.skip("needs Linux's /proc")
    inp = scene(tmp_path)
    status, err = run([str(inp), "-o", str(target), "--quiet"], capsys)
    # As root the folder is attempted and refused; as another user the check before the
    # work already finds /proc not writable. Either way one line naming OUTDIR, exit 2.
    assert_one_line(status, err, f"OUTDIR {target}")
    assert "Errno" not in err


def test_a_name_too_long_for_the_file_system_is_refused_before_any_work(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """OUTDIR failed when it was made ("[Errno 36] File name too long", exit status 1, no
    option named; ``out/<long>/x`` left ``out`` behind), and a --report name only after every
    pair had been matched. 256 bytes: one more than NAME_MAX, in two-byte characters too."""
    inp = scene(tmp_path)
    out = tmp_path / "out"
    long = "x" * 256
    for argv, fragment in (
        (["-o", str(tmp_path / long)], "argument -o/--output: the name 'xxx"),
        (["-o", str(out / long / "x")], "argument -o/--output: the name 'xxx"),
        (["-o", str(out), "--report", str(tmp_path / f"{long}.json")], "argument --report: "),
        (["-o", str(out), "--report", str(tmp_path / ("\u00e9" * 128))], "argument --report: "),
    ):
        status, err = run([str(inp), *argv, "--quiet"], capsys)
        assert_one_line(status, err, fragment)
        assert "bytes long, more than a file name may be (255 bytes)" in err
        assert sorted(p.name for p in tmp_path.iterdir()) == ["in"]


def test_an_unreachable_scheduler_names_the_flag_and_leaves_no_outdir(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The connection's failure (here without waiting for the network: Client raises as it does
    after its timeout) is one line naming --scheduler and the address, and the OUTDIR the job
    had just made is removed again."""
    distributed = pytest.importorskip("distributed")

    def refuse(address: str, **kwargs: object) -> None:
        raise OSError(f"Timed out trying to connect to {address} after 10 s")

    monkeypatch.setattr(distributed, "Client", refuse)
    monkeypatch.setattr(runners, "_handshake", lambda scheduler, timeout: None)
    inp = scene(tmp_path)
    argv = [str(inp), "-o", str(tmp_path / "out"), "--quiet", "--scheduler", "tcp://127.0.0.1:9"]
    status, err = run(argv, capsys)
    assert_one_line(
        status,
        err,
        "--scheduler 'tcp://127.0.0.1:9': cannot reach the Dask scheduler: Timed out trying to "
        "connect to tcp://127.0.0.1:9 after 10 s",
    )
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("link", ["symlink", "hardlink"])
@pytest.mark.parametrize("layout", ["kitti", "pair_names"])
def test_a_pair_of_one_file_found_in_folders_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], link: str, layout: str
) -> None:
    """A CSV line naming one file twice was refused, but a folder's pair linked to one file
    (KITTI's image_3/x.png a link to image_2/x.png, or --pair-names naming a link to the left
    image) was matched with itself: every disparity 0, status ok, exit status 0."""
    inp = tmp_path / "in"
    rng = np.random.default_rng(0)
    left = rng.integers(0, 256, (24, 40), dtype=np.uint8)
    if layout == "kitti":
        (inp / "image_2").mkdir(parents=True)
        (inp / "image_3").mkdir()
        src, dst = inp / "image_2" / "000000_10.png", inp / "image_3" / "000000_10.png"
        extra: list[str] = []
    else:
        (inp / "s").mkdir(parents=True)
        src, dst = inp / "s" / "a.png", inp / "s" / "b.png"
        extra = ["--pair-names", "a", "b"]
    Image.fromarray(left).save(src)
    if link == "symlink":
        dst.symlink_to(src)
    else:
        os.link(src, dst)
    out = tmp_path / "out"
    argv = [str(inp), "-o", str(out), "--focal-px", "700", "--baseline-mm", "100"]
    status, err = run([*argv, "--num-disparities", "16", *extra, "--quiet"], capsys)
    assert_one_line(status, err, f"the left and right image are the same file ({src} and {dst})")
    assert not out.exists()


def test_a_stem_too_long_for_its_file_names_is_refused_before_any_work(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A pair's stem joins its folders' names: 120 + 1 + 130 bytes of them made every output
    name longer than a file name may be, and the pair was matched, then failed to write every
    file, its record included, on every run of the job."""
    inp = tmp_path / "in"
    deep = inp / ("a" * 120) / ("b" * 130)
    deep.mkdir(parents=True)
    rng = np.random.default_rng(0)
    left = rng.integers(0, 256, (24, 40), dtype=np.uint8)
    Image.fromarray(left).save(deep / "left.png")
    Image.fromarray(np.roll(left, -2, axis=1)).save(deep / "right.png")
    out = tmp_path / "out"
    argv = [str(inp), "-o", str(out), "--focal-px", "700", "--baseline-mm", "100"]
    status, err = run([*argv, "--num-disparities", "16", "--quiet"], capsys)
    assert_one_line(status, err, "would be longer than a file name may be (255 bytes)")
    assert "give it a shorter stem in a CSV list" in err
    assert not out.exists()


def test_a_calibration_file_whose_depths_float32_cannot_hold(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # Given with --calib it stops the command before any pair, naming the file; found beside a
    # pair it fails that pair alone, before matching, naming the file too. Both failed each
    # pair after matching, with the library's message (focal_px * baseline_m, float64 input).
    inp = scene(tmp_path)
    calib = inp / "teddy" / "calib.txt"
    calib.write_text(calib.read_text().replace("baseline=100", "baseline=1e40"))
    status, err = run([str(inp), "-o", str(tmp_path / "out"), "--calib", str(calib)], capsys)
    assert_one_line(
        status, err, f"--calib {calib}: focal length 700 px times baseline 1e+37 m is 7e+39 px*m"
    )
    assert not (tmp_path / "out").exists()
    status, err = run([str(inp), "-o", str(tmp_path / "out"), "--quiet"], capsys)
    assert status == 1, err
    record = (tmp_path / "out" / "teddy.record.json").read_text()
    assert f"{calib}: focal length 700 px times baseline 1e+37 m is 7e+39 px*m" in record
    assert not list((tmp_path / "out").glob("teddy.*.npy"))  # failed before matching


def test_more_workers_than_cores_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # --workers had no upper bound: 5000 local worker processes took minutes and gigabytes to
    # start on a 2-core machine, with Ctrl-C and SIGTERM held meanwhile.
    pytest.importorskip("distributed")
    cores = check.available_cores()
    inp = scene(tmp_path)
    argv = [str(inp), "-o", str(tmp_path / "out"), "--quiet", "--workers", str(cores + 1)]
    status, err = run(argv, capsys)
    assert_one_line(
        status, err, f"--workers must be at most {cores} (the cores this process may use), got"
    )
    assert not (tmp_path / "out").exists()


@pytest.fixture
def not_a_scheduler() -> Iterator[Callable[[bytes | None], str]]:
    """A loopback TCP server that accepts connections and then sends ``banner`` (None: says
    nothing, as an HTTP server waiting for a request); returns its tcp:// address. It hangs up
    after 20 s, so that a client that waits for ever fails the test rather than hanging it."""
    servers: list[socket.socket] = []
    stop = threading.Event()

    def serve(banner: bytes | None) -> str:
        srv = socket.create_server(("127.0.0.1", 0))
        servers.append(srv)
        srv.settimeout(0.2)

        def loop() -> None:
            held: list[tuple[float, socket.socket]] = []
            while not stop.is_set():
                for at, conn in [h for h in held if time.monotonic() - h[0] > 20]:
                    conn.close()
                    held.remove((at, conn))
                try:
                    conn, _ = srv.accept()
                except OSError:
                    continue
                held.append((time.monotonic(), conn))
                if banner is not None:
                    conn.sendall(banner)
            for _, conn in held:
                conn.close()

        threading.Thread(target=loop, daemon=True).start()
        return f"tcp://127.0.0.1:{srv.getsockname()[1]}"

    yield serve
    stop.set()
    for srv in servers:
        srv.close()


@pytest.mark.parametrize(
    ("banner", "fragment"),
    [
        (None, "no Dask scheduler answered within 2.5 s"),
        (b"SSH-2.0-OpenSSH_9.2\r\n" + bytes(range(256)) * 4, "is not a Dask scheduler"),
    ],
    ids=["silent", "ssh-banner"],
)
def test_a_scheduler_address_where_something_else_listens_is_one_line(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    not_a_scheduler: Callable[[bytes | None], str],
    banner: bytes | None,
    fragment: str,
) -> None:
    # dask.distributed's Client bounds only the TCP connect: a peer that accepted and said
    # nothing (an HTTP server) held the job for ever, one that sent other bytes gave a
    # traceback (a MemoryError for a frame of exabytes).
    pytest.importorskip("distributed")
    monkeypatch.setattr(runners, "SCHEDULER_TIMEOUT_S", 0.5)
    address = not_a_scheduler(banner)
    inp = scene(tmp_path)
    argv = [str(inp), "-o", str(tmp_path / "out"), "--quiet", "--scheduler", address]
    started = time.monotonic()
    status, err = run(argv, capsys)
    assert time.monotonic() - started < 30
    assert_one_line(status, err, f"--scheduler {address!r}: ")
    assert fragment in err, err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("quiet", [False, True], ids=["summary", "quiet"])
@pytest.mark.parametrize("brk", ["\n", "\r", "\x85", "\u2028"], ids=["LF", "CR", "NEL", "LS"])
def test_a_failed_pair_is_reported_on_one_line_whatever_its_name_holds(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], quiet: bool, brk: str
) -> None:
    # A pair whose folder and image names hold a line break (the file system allows it): its
    # stem and its error, which names the file, were printed over two lines, the second
    # without the prefix. Escaped, the names stay what they are.
    pytest.importorskip("PIL.Image")
    inp, out = tmp_path / "in", tmp_path / "out"
    scene = inp / f"sc{brk}ene"
    scene.mkdir(parents=True)
    (scene / "left.png").write_bytes(b"not a png")
    (scene / "right.png").write_bytes(b"not a png either")
    args = ["batch", str(inp), "-o", str(out), "--focal-px", "700", "--baseline-mm", "100"]
    args += ["--num-disparities", "32"] + (["--quiet"] if quiet else [])
    assert cli.main(args) == 1
    captured = capsys.readouterr()
    text = captured.err if quiet else captured.out
    lines = text.splitlines()
    failed = [
        line for line in lines if line.startswith(("  failed ", "stereodepth batch: failed "))
    ]
    assert len(failed) == 1, lines
    shown = repr(brk)[1:-1]
    assert "cannot decode image" in failed[0], failed
    assert f"sc{shown}ene/left.png" in failed[0] or f"sc{shown}ene/right.png" in failed[0]
    assert all(line.startswith(("stereodepth batch:", "  ", "1 pair", "report:")) for line in lines)


def test_a_report_of_the_users_is_refused_without_force(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A file at the report's path that is not a batch report (OUTDIR/report.json of the
    user's, or --report naming one) is refused, unchanged, as a file of theirs at a pair's
    output name is; --force replaces it, and a report of the job's own is replaced on the
    next run without --force."""
    inp = scene(tmp_path)
    out = tmp_path / "out"
    out.mkdir()
    mine = out / "report.json"
    elsewhere = tmp_path / "notes.json"
    for report, extra in ((mine, []), (elsewhere, ["--report", str(elsewhere)])):
        for text in ("MINE\n", '{"counts": 3}'):
            report.write_text(text)
            before = {f: f.stat().st_mtime_ns for f in out.iterdir()}
            status, err = run([str(inp), "-o", str(out), "--quiet", *extra], capsys)
            assert_one_line(
                status,
                err,
                f"--report {report}: an existing file that is not a batch report (a file of "
                "yours?)",
            )
            assert report.read_text() == text
            assert {f: f.stat().st_mtime_ns for f in out.iterdir()} == before  # no pair ran
        status, err = run([str(inp), "-o", str(out), "--quiet", "--force", *extra], capsys)
        assert status == 0, err
        assert json.loads(report.read_text())["counts"]["ok"] == 1
        status, err = run([str(inp), "-o", str(out), "--quiet", *extra], capsys)
        assert status == 0, err  # its own report: replaced
        assert json.loads(report.read_text())["counts"]["skipped"] == 1
