"""Headless Chromium (Debian's package ``chromium``) driven over the DevTools protocol on a pipe
(``--remote-debugging-pipe``: JSON commands on fd 3, answers on fd 4, each ended by a NUL), so a
test can screenshot a page served on localhost with nothing from PyPI but Pillow, and no
browser download. :func:`chromium` is None where no Chromium is installed."""

from __future__ import annotations

import base64
import io
import json
import os
import shutil
import subprocess
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
