"""A second process that encodes false-colour PNGs beside this one.

The false-colour pictures of a run can only be drawn once the loop is done
(they share the scale of the whole run), and Pillow's PNG encoder holds the
GIL for the whole encoding (~30 ms for a 512 x 512 picture), so threads cannot
share them; a process can.  ``start`` forks the worker at the very beginning
of ``gammac run``, while no other thread exists (forking costs this process
~1 ms), and the worker waits.  Whether the run makes pictures is known only
once the effect is checked and the scene loaded: then ``prepare`` has the
worker import Pillow (only: ~0.03 s of its CPU, while the setup runs), and
a run without pictures never has it do anything.  ``FalseColourWriter``
hands it every other picture of the run and encodes the others itself
meanwhile.

Both sides make the PNG with ``titled_png`` from the same pixels (the
canvas's frame, the picture) and the same font (``canvas_font``), so the
worker's bytes are those this process would write; the files are still
written here, in order.  Whatever goes wrong with the worker (it died, it
failed) only means the picture is encoded here.  The worker ignores SIGINT
and SIGTERM (the run handles them), holds none of this process's files (its
standard streams are /dev/null, every other descriptor closed) and leaves
when this process closes its end of the pipe, or exits, or dies.
"""

from __future__ import annotations

import os
import pickle
import signal
import threading

_worker: "PngWorker | None" = None


class WorkerFailed(Exception):
    pass


class PngWorker:
    def __init__(self, pid: int, jobs, results):
        self.pid, self._jobs, self._results = pid, jobs, results
        self.alive = True

    def send(self, frame, font_height: int, title: str, picture) -> None:
        """Give the worker a picture (uint8 [h, w, 3]) to encode as
        ``titled_png(frame, picture, title, canvas_font(font_height))`` does;
        ``receive`` returns the PNG."""
        job = (frame.size, frame.tobytes(), font_height, title, (picture.shape[1], picture.shape[0]),
               picture.tobytes())
        try:
            pickle.dump(job, self._jobs, protocol=pickle.HIGHEST_PROTOCOL)
            self._jobs.flush()
        except (OSError, ValueError, pickle.PickleError) as err:
            self.alive = False
            raise WorkerFailed(str(err)) from None

    def receive(self) -> bytes:
        try:
            status, value = pickle.load(self._results)
        except (OSError, EOFError, ValueError, pickle.UnpicklingError) as err:
            self.alive = False
            raise WorkerFailed(str(err) or "the worker is gone") from None
        if status != "ok":
            raise WorkerFailed(value)
        return value

    def close(self) -> None:
        self.alive = False
        for stream in (self._jobs, self._results):
            try:
                stream.close()
            except OSError:
                pass
        try:
            os.waitpid(self.pid, os.WNOHANG)
        except OSError:
            pass


    def prepare(self) -> None:
        """Have the worker import Pillow now (pictures will be sent)."""
        try:
            pickle.dump(PREPARE, self._jobs, protocol=pickle.HIGHEST_PROTOCOL)
            self._jobs.flush()
        except (OSError, ValueError, pickle.PickleError):
            self.alive = False


#: The message that has the worker import Pillow before the first picture.
PREPARE = "prepare"


def canvas_font(height: int):
    """The font of a false-colour picture ``height`` pixels high: Pillow's
    default font, scaled (its bitmap font where Pillow lacks FreeType); a new
    one each time (loading it costs ~0.2 ms; a FreeType face is not shared
    between threads)."""
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=max(11, height // 40))
    except TypeError:  # Pillow without FreeType
        return ImageFont.load_default()


#: zlib level of the false-colour PNGs: 1 encodes in half the time of
#: Pillow's default 6 (the pictures are drawn after the loop, where a user
#: waits for them) for files ~20 % larger.
PNG_COMPRESS_LEVEL = 1


def titled_png(frame, picture, title: str, font) -> bytes:
    """The PNG of ``picture`` (an RGB image) at the top left of ``frame`` (the
    canvas: colour bar and ticks), ``title`` written over it."""
    import io

    from PIL import ImageDraw

    canvas = frame.copy()
    canvas.paste(picture, (0, 0))
    ImageDraw.Draw(canvas).text((10, 10), title, fill=(0, 0, 0), font=font)
    out = io.BytesIO()
    canvas.save(out, format="PNG", compress_level=PNG_COMPRESS_LEVEL)
    return out.getvalue()


def start() -> None:
    """Fork the worker, if this process has no other thread (forking one
    with threads is unsafe) and none is running yet."""
    global _worker
    if _worker is not None or not hasattr(os, "fork") or threading.active_count() != 1:
        return
    jobs_r, jobs_w = os.pipe()
    results_r, results_w = os.pipe()
    try:
        pid = os.fork()
    except OSError:
        for fd in (jobs_r, jobs_w, results_r, results_w):
            os.close(fd)
        return
    if pid == 0:
        _serve(jobs_r, results_w, keep=(jobs_r, results_w))     # never returns
    os.close(jobs_r)
    os.close(results_w)
    _worker = PngWorker(pid, os.fdopen(jobs_w, "wb"), os.fdopen(results_r, "rb"))


def prepare() -> None:
    """The run will make pictures: the worker (if any) gets ready for them."""
    if _worker is not None and _worker.alive:
        _worker.prepare()


def worker() -> PngWorker | None:
    """The running worker, or None (then encode here)."""
    return _worker if _worker is not None and _worker.alive else None


def stop() -> None:
    global _worker
    if _worker is not None:
        _worker.close()
        _worker = None


def _serve(jobs_fd: int, results_fd: int, keep: tuple) -> None:
    """The worker's life: encode pictures until the pipe closes, then leave
    without running any of the parent's exit handlers."""
    try:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        null = os.open(os.devnull, os.O_RDWR)
        for fd in (0, 1, 2):
            os.dup2(null, fd)
        low = 3
        for fd in sorted(keep):
            os.closerange(low, fd)
            low = fd + 1
        os.closerange(low, 1 << 16)
        jobs, results = os.fdopen(jobs_fd, "rb"), os.fdopen(results_fd, "wb")
        while True:
            try:
                job = pickle.load(jobs)
            except EOFError:
                break
            from PIL import Image

            if job == PREPARE:
                Image.preinit()
                continue
            frame_size, frame, font_height, title, size, picture = job
            try:
                reply = ("ok", titled_png(Image.frombytes("RGB", frame_size, frame),
                                          Image.frombytes("RGB", size, picture), title, canvas_font(font_height)))
            except Exception as err:  # noqa: BLE001 - reported to the parent, which encodes instead
                reply = ("error", f"{type(err).__name__}: {err}")
            pickle.dump(reply, results, protocol=pickle.HIGHEST_PROTOCOL)
            results.flush()
    finally:
        os._exit(0)
