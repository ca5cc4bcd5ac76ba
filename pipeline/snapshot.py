"""`python -m pipeline snapshot RECORDING.rrd [--frames 0,45,-1] [-o DIR] [--tab NAME] [--turn DEG]`: PNGs
of a recording's 3D views at chosen frames, through the real Rerun viewer.

The viewer binary shipped with rerun-sdk runs headless (it needs no display; on a machine without a
GPU it renders through software Vulkan: Debian packages `mesa-vulkan-drivers` and `libvulkan1`,
`WGPU_BACKEND=vulkan`, which this command sets when it is unset), bound to 127.0.0.1 on a free
port, with its own scratch config and data folders so a user's saved layout does not apply. It is
always stopped: on success, on an error, on Ctrl-C.

Files, for a recording `NAME.rrd` (TAB is the opening tab unless `--tab` names another):
- `NAME_open.png`: the whole viewer as the file opens (the blueprint's layout, playing);
- `NAME_fNNN.png`: the tab's first 3D view (the overview's scene view) paused at frame NNN, and
  `NAME_fNNN_v2.png` ... for the tab's further 3D views (the rig tab has two);
- `NAME_fNNN_viewer.png`: the whole viewer at that frame.
With `--tab TAB` the names are `NAME_TAB_...`; with `--turn DEG` (every 3D view's camera turned DEG
degrees about its up axis through what it looks at: 180 looks from behind) `NAME_turnDEG_...`.

Something missing (the viewer binary, a Vulkan loader or driver, a viewer that does not start)
is one line `error: ...` and exit 2.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import glob
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

EXIT_MISSING = 2
PACKAGES = "apt-get install mesa-vulkan-drivers libvulkan1"


class SnapshotError(Exception):
    """Something the snapshot needs is missing or failed: one line for the user, exit 2."""


def viewer_binary() -> Path:
    try:
        import rerun_cli
    except ImportError:
        raise SnapshotError("no Rerun viewer: the rerun_cli package (installed with rerun-sdk) is missing; "
                            "pip install rerun-sdk") from None
    exe = Path(rerun_cli.__file__).parent / ("rerun.exe" if os.name == "nt" else "rerun")
    if not exe.is_file():
        raise SnapshotError(f"no Rerun viewer binary at {exe}; reinstall rerun-sdk")
    return exe


def check_vulkan(env: dict) -> None:
    """On Linux, the viewer renders through Vulkan: the loader library and at least one driver (a
    GPU's, or Mesa's software lavapipe) must be installed."""
    if not sys.platform.startswith("linux") or env.get("WGPU_BACKEND", "vulkan").lower() not in ("vulkan", "vk"):
        return
    lib = ctypes.util.find_library("vulkan") or "libvulkan.so.1"
    try:
        ctypes.CDLL(lib)
    except OSError:
        raise SnapshotError(f"no Vulkan loader (libvulkan.so.1) for the headless viewer; install it and a driver: "
                            f"{PACKAGES}") from None
    icds = env.get("VK_ICD_FILENAMES") or env.get("VK_DRIVER_FILES")
    if icds:
        found = [p for p in icds.split(os.pathsep) if Path(p).is_file()]
    else:
        found = [p for d in ("/usr/share/vulkan/icd.d", "/etc/vulkan/icd.d", "/usr/local/share/vulkan/icd.d")
                 for p in glob.glob(f"{d}/*.json")]
    if not found:
        raise SnapshotError(f"no Vulkan driver (no ICD file in /usr/share/vulkan/icd.d) for the headless viewer; "
                            f"{PACKAGES} (mesa-vulkan-drivers renders in software without a GPU)")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def parse_frames(text: str) -> list[int]:
    try:
        return [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise SnapshotError(f"--frames: expected comma-separated frame numbers (-1 = last), got {text!r}") from None


class Viewer:
    """The headless viewer process and a client on it; a context manager that always stops it."""

    def __init__(self, *, timeout: float = 60.0):
        self.exe = viewer_binary()
        env = dict(os.environ)
        env.setdefault("WGPU_BACKEND", "vulkan")
        check_vulkan(env)
        self.scratch = tempfile.TemporaryDirectory(prefix="snapshot-")
        self.env = dict(env, XDG_DATA_HOME=self.scratch.name, XDG_CONFIG_HOME=self.scratch.name,
                        XDG_CACHE_HOME=self.scratch.name)
        self.timeout = timeout
        self.proc = None
        self.log_path = Path(self.scratch.name) / "viewer.log"

    def __enter__(self):
        try:
            return self._start()
        except BaseException:   # an error or Ctrl-C while it starts: `with` would not call __exit__
            self.__exit__(None, None, None)
            raise

    def _start(self):
        from rerun.experimental import ViewerClient
        port = free_port()
        log = open(self.log_path, "w")
        self.proc = subprocess.Popen([str(self.exe), "--headless", "--bind", "127.0.0.1", "--port", str(port),
                                      "--hide-welcome-screen"], env=self.env, stdout=log, stderr=subprocess.STDOUT,
                                     stdin=subprocess.DEVNULL)
        log.close()
        deadline = time.monotonic() + self.timeout
        while True:   # poll until the viewer answers (it compiles shaders and opens its port first)
            if self.proc.poll() is not None:
                raise SnapshotError(f"the Rerun viewer exited at start (code {self.proc.returncode}): "
                                    f"{self.last_log_line()}")
            try:
                self.client = ViewerClient.connect(f"rerun+http://127.0.0.1:{port}/proxy")
                self.client.get_state()
                return self
            except Exception:   # not listening yet
                if time.monotonic() > deadline:
                    raise SnapshotError(f"the Rerun viewer did not answer within {self.timeout:.0f} s: "
                                        f"{self.last_log_line()}") from None
                time.sleep(0.2)

    def last_log_line(self) -> str:
        try:
            lines = [ln.strip() for ln in self.log_path.read_text(errors="replace").splitlines() if ln.strip()]
        except OSError:
            lines = []
        errors = [ln for ln in lines if "ERROR" in ln or "rror" in ln or "panick" in ln]
        return (errors or lines or ["no output"])[-1][:300]

    def __exit__(self, *exc):
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(10)
        self.scratch.cleanup()
        return False


def _tab_views(bp: dict, tab: str | None) -> tuple[str | None, list[str], str | None]:
    """(tabs container path, view ids in the chosen tab depth first, the tab's entry); tab None:
    the active one. A blueprint without tabs: every view."""
    def kids(path):   # the viewer reports a single entry as a string, not a list
        c = bp.get(path, {}).get("ContainerBlueprint", {}).get("contents", [])
        return [c] if isinstance(c, str) else list(c)
    tabs = next((p for p, v in bp.items() if v.get("ContainerBlueprint", {}).get("container_kind") == "Tabs"), None)
    if tabs is None:
        if tab is not None:
            raise SnapshotError(f"--tab: the recording's blueprint has no tabs")
        return None, [p.split("/", 2)[2] for p, v in bp.items() if p.startswith("/view/") and "ViewBlueprint" in v], None
    entries = kids(tabs)
    if tab is None:
        chosen = bp[tabs]["ContainerBlueprint"].get("active_tab") or (entries[0] if entries else None)
    else:
        def name(e):
            item = bp.get("/" + e, {})
            return (item.get("ContainerBlueprint") or item.get("ViewBlueprint") or {}).get("display_name")
        chosen = next((e for e in entries if name(e) == tab), None)
        if chosen is None:
            raise SnapshotError(f"--tab: no tab {tab!r}; tabs: {', '.join(str(name(e)) for e in entries)}")
    out, stack = [], [chosen]
    while stack:
        e = stack.pop(0)
        if e.startswith("view/"):
            out.append(e.split("/", 1)[1])
        else:
            stack[:0] = kids("/" + e)
    return tabs, out, chosen


def turned(eye: dict, degrees: float) -> dict:
    """An EyeControls3D blueprint entry ({position, look_target, eye_up}) with its position turned
    `degrees` about eye_up through look_target (Rodrigues' formula; counter-clockwise seen from above)."""
    import numpy as np
    up = np.asarray(eye["eye_up"], float)
    up = up / max(np.linalg.norm(up), 1e-12)
    c = np.asarray(eye["look_target"], float)
    r = np.asarray(eye["position"], float) - c
    a = np.radians(degrees)
    r = r * np.cos(a) + np.cross(up, r) * np.sin(a) + up * (up @ r) * (1.0 - np.cos(a))
    return {**eye, "position": [float(v) for v in c + r]}


def snapshot(rrd: Path, frames: list[int], out: Path, *, tab: str | None = None, timeline: str = "frame",
             turn: float = 0.0, echo=print) -> list[Path]:
    """Write the PNGs (see the module docstring); returns their paths."""
    from stages.input_files import check_regular_file
    rrd = Path(rrd).resolve()
    check_regular_file(rrd, "recording", SnapshotError)   # a FIFO or device would hang the viewer
    viewer = Viewer()   # checks the binary and Vulkan before anything is written
    out = Path(out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    stem = rrd.stem + (f"_{tab}" if tab else "") + (f"_turn{turn:g}" if turn else "")
    written = []
    with viewer:
        v = viewer.client
        v.open(str(rrd))
        deadline = time.monotonic() + 120
        while v.get_state().loading:
            if time.monotonic() > deadline:
                raise SnapshotError(f"{rrd}: the viewer did not finish loading it in 120 s")
            time.sleep(0.2)
        st = v.get_state()
        rec = next((r for r in st.recordings if r.store_id == st.active_recording), None)
        if rec is None:
            raise SnapshotError(f"{rrd}: the viewer opened no recording from it (not an .rrd recording?)")
        tl = next((t for t in rec.timelines if t.name == timeline), None)
        if tl is None:
            raise SnapshotError(f"{rrd}: no timeline {timeline!r}; it has {[t.name for t in rec.timelines]}")
        bp = v.get_blueprint().blueprint
        tabs, view_ids, chosen = _tab_views(bp, tab)
        if tab is not None and tabs is not None:
            bp[tabs]["ContainerBlueprint"]["active_tab"] = chosen
        if turn:
            for key, entry in bp.items():
                if "EyeControls3D" in entry and {"position", "look_target", "eye_up"} <= set(entry["EyeControls3D"]):
                    entry["EyeControls3D"] = turned(entry["EyeControls3D"], turn)
        if turn or (tab is not None and tabs is not None):
            v.set_blueprint(bp, of="recording")
        if tab is None:
            p = out / f"{stem}_open.png"
            p.write_bytes(v.take_screenshot())
            written.append(p)
        classes = {w.view_id: w.view_class for w in v.get_state().views}
        views3d = [i for i in view_ids if classes.get(i) == "3D"]
        if not views3d:
            raise SnapshotError(f"{rrd}: the {'tab ' + repr(tab) if tab else 'opening tab'} has no 3D view")
        for f in frames:
            g = tl.end + 1 + f if f < 0 else f
            if not tl.start <= g <= tl.end:
                raise SnapshotError(f"--frames: {f} is outside the recording's {timeline} range {tl.start}..{tl.end}")
            v.set_time(timeline, sequence=g, play_state="paused")
            for k, vid in enumerate(views3d):
                p = out / f"{stem}_f{g:03d}{'' if k == 0 else f'_v{k + 1}'}.png"
                p.write_bytes(v.take_screenshot(vid))
                written.append(p)
            p = out / f"{stem}_f{g:03d}_viewer.png"
            p.write_bytes(v.take_screenshot())
            written.append(p)
            echo(f"frame {g}: {out / f'{stem}_f{g:03d}.png'}")
        for e in v.get_logs():
            if e.level in ("WARN", "ERROR") and "oftware rasterizer" not in e.message:
                echo(f"viewer {e.level.lower()}: {e.message[:300]}")
    return written


def main(args) -> int:
    try:
        snapshot(Path(args.recording), parse_frames(args.frames), Path(args.out), tab=args.tab,
                 timeline=args.timeline, turn=args.turn)
    except SnapshotError as err:
        print(f"error: {err}", file=sys.stderr)
        return EXIT_MISSING
    except KeyboardInterrupt:
        print("\ninterrupted: the viewer was stopped", file=sys.stderr)
        return 130
    except (TimeoutError, ConnectionError, OSError) as err:   # the viewer stopped answering (it was stopped)
        print(f"error: {args.recording}: the Rerun viewer failed: {type(err).__name__}: "
              f"{' '.join(str(err).split())[:300]} (it was stopped; try again on a less loaded machine)",
              file=sys.stderr)
        return EXIT_MISSING
    return 0
