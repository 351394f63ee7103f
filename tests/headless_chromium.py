"""Headless Chromium (Debian's package ``chromium``) driven over the DevTools protocol on a pipe
(``--remote-debugging-pipe``: JSON commands on fd 3, answers on fd 4, each ended by a NUL), so a
test can screenshot a page served on localhost with nothing from PyPI but Pillow, and no
browser download. :func:`chromium` is None where no Chromium is installed; :func:`install`
installs Debian's package where it can (as root, with apt-get) and says why not where it cannot
(``python tests/headless_chromium.py`` does so: ``make test`` runs it first). :func:`panes` cuts
a screenshot of Rerun's viewer into its views."""

from __future__ import annotations

import base64
import io
import json
import os
import shutil
import subprocess
import tempfile
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
import numpy.typing as npt

#: As root, on a closed network, without a GPU: no sandbox, no background fetches, SwiftShader.
FLAGS = (
    "--headless", "--no-sandbox", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
    "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--remote-debugging-pipe",
)  # fmt: skip


def chromium() -> str | None:
    """The Chromium executable on PATH, None if there is none."""
    return next((p for name in ("chromium", "chromium-browser") if (p := shutil.which(name))), None)


#: Where :func:`install` writes why it could not install Chromium (read by the tests' skip).
WHY_NOT = Path(tempfile.gettempdir()) / "quadswarm-no-chromium.txt"


def install(timeout_s: float = 900.0) -> tuple[str | None, str]:
    """Chromium's executable, installing Debian's ``chromium`` with apt-get if it is missing
    (as root; ``apt-get update`` first if the package is unknown); else None and why not."""
    found = chromium()
    if found is not None:
        return found, "installed"
    if shutil.which("apt-get") is None:
        return None, "no apt-get here (not Debian or Ubuntu): install a Chromium by hand"
    if os.geteuid() != 0:
        return None, "apt-get install chromium needs root: run it as root (sudo)"
    env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
    command = ["apt-get", "install", "-y", "-q", "chromium"]
    try:
        done = subprocess.run(command, capture_output=True, text=True, env=env, timeout=timeout_s)
        if done.returncode != 0:
            subprocess.run(["apt-get", "update", "-q"], capture_output=True, env=env,
                           timeout=timeout_s)  # fmt: skip
            done = subprocess.run(
                command, capture_output=True, text=True, env=env, timeout=timeout_s
            )
    except subprocess.TimeoutExpired:
        return None, f"apt-get install chromium took over {timeout_s:.0f} s"
    if done.returncode != 0:
        last = (done.stderr or done.stdout).strip().splitlines()[-1:] or ["no output"]
        return None, f"apt-get install chromium failed ({done.returncode}): {last[0]}"
    found = chromium()
    return found, "installed" if found else "apt-get installed chromium but it is not on PATH"


def why_not() -> str:
    """Why there is no Chromium here: what :func:`install` last said, or how to install it."""
    if WHY_NOT.exists():
        return WHY_NOT.read_text().strip()
    return "not installed (Debian: apt-get install chromium, or make test, which installs it)"


#: Rerun's light theme draws the borders between views as 1-px lines of this grey.
BORDER_GREY = 223


def _long_runs(mask: npt.NDArray[np.bool_], length: int) -> npt.NDArray[np.bool_]:
    """The pixels of ``mask`` (H, W) in horizontal runs at least ``length`` long."""
    padded = np.pad(mask, ((0, 0), (1, 1))).astype(np.int8)
    edges = np.diff(padded, axis=1)
    out = np.zeros_like(mask)
    for row, start in zip(*np.nonzero(edges == 1), strict=True):
        stop = int(np.flatnonzero(edges[row, start:] == -1)[0]) + start
        if stop - start >= length:
            out[row, start:stop] = True
    return out


def panes(pixels: npt.NDArray[np.int_], min_line: int = 40) -> npt.NDArray[np.int_]:
    """(H, W) labels of the regions of a screenshot of Rerun's viewer (H, W, 3) that its views'
    borders (straight lines of :data:`BORDER_GREY` at least ``min_line`` px, thickened by 1 px to
    close the gaps at their corners) enclose: 1, 2, ... one per view (a tab bar may join the view
    under it), 0 on the borders."""
    from scipy import ndimage

    grey = np.abs(pixels - BORDER_GREY).max(axis=2) <= 2
    lines = _long_runs(grey, min_line) | _long_runs(grey.T, min_line).T
    walls = ndimage.binary_dilation(lines, iterations=1)
    labels, _ = ndimage.label(~walls)
    return np.asarray(labels, dtype=int)


class HeadlessChromium:
    """Chromium showing ``url`` in a ``size`` window with a fresh profile in ``profile``."""

    def __init__(
        self, executable: str, url: str, profile: Path, size: tuple[int, int] = (1280, 800)
    ) -> None:
        cmd_read, cmd_write = os.pipe()
        out_read, out_write = os.pipe()

        def onto_3_and_4() -> None:  # in the child: the protocol's file descriptors
            a, b = os.dup(cmd_read), os.dup(out_write)
            os.dup2(a, 3)
            os.dup2(b, 4)

        self._proc = subprocess.Popen(
            [executable, *FLAGS, f"--user-data-dir={profile}",
             f"--window-size={size[0]},{size[1]}", url],
            preexec_fn=onto_3_and_4, close_fds=False,
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )  # fmt: skip
        os.close(cmd_read)
        os.close(out_write)
        self._to = os.fdopen(cmd_write, "wb", buffering=0)
        self._from = os.fdopen(out_read, "rb", buffering=0)
        self._buffer = b""
        self._id = 0
        page = next(t for t in self.call("Target.getTargets")["targetInfos"] if t["type"] == "page")
        self._session = self.call("Target.attachToTarget", targetId=page["targetId"], flatten=True)[
            "sessionId"
        ]

    def call(self, method: str, session: str | None = None, **params: Any) -> dict[str, Any]:
        """One DevTools command; its result (RuntimeError on an error or if Chromium ended)."""
        self._id += 1
        message: dict[str, Any] = {"id": self._id, "method": method, "params": params}
        if session is not None:
            message["sessionId"] = session
        self._to.write(json.dumps(message).encode() + b"\0")
        while True:
            while b"\0" not in self._buffer:
                chunk = self._from.read(1 << 16)
                if not chunk:
                    raise RuntimeError(f"Chromium ended (exit {self._proc.poll()})")
                self._buffer += chunk
            raw, self._buffer = self._buffer.split(b"\0", 1)
            reply = json.loads(raw)
            if reply.get("id") == self._id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return dict(reply["result"])

    def screenshot(self) -> npt.NDArray[np.int_]:
        """The page as it is now: (H, W, 3) RGB."""
        from PIL import Image

        data = self.call("Page.captureScreenshot", self._session, format="png")["data"]
        with Image.open(io.BytesIO(base64.b64decode(data))) as image:
            return np.asarray(image.convert("RGB"), dtype=int)

    def close(self) -> None:
        self._to.close()
        self._from.close()
        self._proc.terminate()
        try:
            self._proc.wait(10)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait(10)

    def __enter__(self) -> HeadlessChromium:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


if __name__ == "__main__":
    executable, why = install()
    if executable is None:
        WHY_NOT.write_text(f"no Chromium: {why}\n")
        print(f"headless Chromium: none, the viewer's screenshot test will be skipped: {why}")
    else:
        WHY_NOT.unlink(missing_ok=True)
        print(f"headless Chromium: {executable}")
