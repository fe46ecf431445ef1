"""Queued bulk-IN transfers on the data endpoint: many requests in flight, reaped in order.

pyusb has one synchronous read in flight at a time; while Python is busy between two reads
(the GIL held by decoding or analysis), the endpoint has no request pending, the camera's
small FIFO fills and events are lost. The HAL keeps 20 asynchronous transfers of 128 KiB
queued (``docs/evk-usb.md`` 1.4), the Rust ``neuromorphic-drivers`` 32: the host controller
then fills them with no help from Python.

A transfer queue has four calls, the same on every backend:

``submit(buffer, timeout_ms)``
    queue a bulk-IN request into ``buffer`` (a writable ``array.array('B')``);
``reap(timeout_s)``
    the oldest submitted request once it has completed (:class:`Done`), else ``None`` after
    ``timeout_s``; requests always come out in submission order, so the bytes stay ordered;
``cancel()``
    cancel every pending request; each still comes out of ``reap``, with the data it got;
``close()``
    free the queue (after every request was reaped).

:func:`open_queue` finds one: the backend's own ``bulk_in_queue`` hook when it has one (the
file-backed fake :class:`capture.evk.fake.FakeEVK`), else :class:`LibusbQueue` on pyusb's
libusb-1.0 backend, through the ctypes bindings of python-libusb1 (``usb1``) on the very
library, context and device handle that pyusb opened: control traffic stays on pyusb, and one
handle owns the interface (a second libusb handle could not claim it). Other pyusb backends
(libusb0, OpenUSB) get ``None``: the caller falls back to one synchronous read at a time.
"""

from __future__ import annotations

import ctypes
import errno
import time
from collections import deque
from typing import NamedTuple

import usb.core

STATUSES = ("completed", "error", "timed_out", "cancelled", "stall", "no_device", "overflow")
"""Transfer status names, indexed by libusb's ``enum libusb_transfer_status``."""


class Done(NamedTuple):
    """A reaped transfer: ``nbytes`` of data at the start of ``buffer``, and its status (one
    of :data:`STATUSES`; ``completed`` and ``timed_out`` are both normal, the latter possibly
    with data)."""

    buffer: object
    nbytes: int
    status: str


def open_queue(dev: usb.core.Device, ep: int):
    """A transfer queue on endpoint ``ep`` of the claimed pyusb device ``dev``, or ``None``
    when its backend cannot queue transfers.

    Raises
    ------
    usb.core.USBError
        The device cannot be opened.
    """
    ctx = dev._ctx  # pyusb's resource manager: the backend and the open device handle
    ctx.managed_open()
    backend = ctx.backend
    hook = getattr(backend, "bulk_in_queue", None)
    if hook is not None:
        return hook(ctx.handle, ep)
    try:
        import usb.backend.libusb1 as pyusb_libusb1
    except ImportError:  # pragma: no cover - pyusb always ships it
        return None
    if not isinstance(backend, pyusb_libusb1._LibUSB):
        return None
    return LibusbQueue(backend, ctx.handle, ep)


def _bindings(lib):
    """python-libusb1's ctypes bindings on ``lib`` (pyusb's libusb-1.0, a ``ctypes.CDLL``), checked to
    sit on it (python-libusb1 keeps the first library it loaded): transfers submitted through one must
    complete in the other's event loop."""
    import usb1

    usb1.loadLibrary(lib)  # False where it had loaded one already: the same library or not, as checked below
    import usb1.libusb1 as bindings

    def address(library, name):
        return ctypes.cast(getattr(library, name), ctypes.c_void_p).value

    if address(bindings.libusb, "libusb_submit_transfer") != address(lib, "libusb_submit_transfer"):
        raise RuntimeError("python-libusb1 and pyusb loaded two different libusb-1.0 libraries")
    return bindings


class LibusbQueue:
    """Asynchronous bulk-IN transfers through libusb-1.0, on pyusb's context and handle.

    Completions are handled by whichever thread runs libusb's events (``reap``, or pyusb's
    own synchronous control transfers on another thread); the callback only records which
    transfer is done. Written for Linux (usbfs), where cancelling or timing out one request
    leaves the others on the endpoint pending; on Windows and macOS libusb aborts them all.

    Parameters
    ----------
    backend : usb.backend.libusb1._LibUSB
        pyusb's libusb-1.0 backend (its ``lib`` and ``ctx``).
    handle : object
        pyusb's open device handle (its ``handle`` is the ``libusb_device_handle *``).
    ep : int
        Bulk-IN endpoint address.
    """

    def __init__(self, backend, handle, ep: int):
        self._lib = _bindings(backend.lib)
        lib = self._lib
        self._ctx = ctypes.c_void_p(backend.ctx.value)
        self._handle = ctypes.cast(handle.handle, lib.libusb_device_handle_p)
        self._ep = ep
        self._order: deque = deque()  # (transfer pointer, buffer), in submission order
        self._done: set[int] = set()
        self._spare: list = []
        self._callback = lib.libusb_transfer_cb_fn_p(self._completed)  # kept alive with the queue

    def _completed(self, transfer_p) -> None:
        self._done.add(ctypes.addressof(transfer_p.contents))

    @property
    def pending(self) -> int:
        """Requests submitted and not yet reaped."""
        return len(self._order)

    @property
    def incomplete(self) -> int:
        """Requests still on the endpoint (submitted, not complete), as of the last event handling."""
        return len(self._order) - len(self._done)

    def submit(self, buffer, timeout_ms: int) -> None:
        """Queue a bulk-IN request filling ``buffer`` (``array.array('B')``)."""
        lib = self._lib
        t = self._spare.pop() if self._spare else lib.libusb_alloc_transfer(0)
        if not t:
            raise MemoryError("libusb_alloc_transfer failed")
        address, length = buffer.buffer_info()
        c = t.contents
        c.dev_handle = self._handle
        c.flags = 0
        c.endpoint = self._ep
        c.type = lib.LIBUSB_TRANSFER_TYPE_BULK
        c.timeout = int(timeout_ms)
        c.length = length
        c.actual_length = 0
        c.buffer = address  # a c_void_p field
        c.callback = self._callback
        c.user_data = None
        rc = lib.libusb_submit_transfer(t)
        if rc:
            self._spare.append(t)
            raise _usb_error(rc, "submitting a bulk transfer")
        self._order.append((t, buffer))

    def reap(self, timeout_s: float) -> Done | None:
        """The oldest request once complete, or ``None`` after ``timeout_s`` seconds (0: without
        waiting). The completions due are handled at least once, so :attr:`incomplete` is current."""
        if not self._order:
            return None
        t, buffer = self._order[0]
        key = ctypes.addressof(t.contents)
        deadline = time.monotonic() + timeout_s
        self._handle_events(0.0)  # once in any case: ``incomplete`` is then current
        while key not in self._done:
            left = deadline - time.monotonic()
            if left <= 0:
                return None
            self._handle_events(left)
        self._done.discard(key)
        self._order.popleft()
        c = t.contents
        status = STATUSES[c.status] if 0 <= c.status < len(STATUSES) else "error"
        done = Done(buffer, int(c.actual_length), status)
        self._spare.append(t)
        return done

    def _handle_events(self, timeout_s: float) -> None:
        """Run libusb's completions, waiting up to ``timeout_s`` (at most 10 ms, at least 1 µs: another
        thread may be handling ours)."""
        lib = self._lib
        tv = lib.timeval(0, max(int(min(timeout_s, 0.01) * 1e6), 1))
        rc = lib.libusb_handle_events_timeout_completed(self._ctx, ctypes.byref(tv), None)
        if rc and rc != -10:  # LIBUSB_ERROR_INTERRUPTED: just go round again
            raise _usb_error(rc, "handling USB events")

    def cancel(self) -> None:
        """Cancel every pending request (those already complete are unaffected)."""
        for t, _ in self._order:
            self._lib.libusb_cancel_transfer(t)  # NOT_FOUND for one already complete: fine

    def close(self) -> None:
        """Cancel and reap what is left, then free every transfer."""
        self.cancel()
        end = time.monotonic() + 2.0
        while self._order and time.monotonic() < end:
            self.reap(0.1)
        if self._order:  # never completed: freeing them would let libusb write into freed memory
            raise usb.core.USBError("transfers still pending after cancel", None, errno.EIO)
        for t in self._spare:
            self._lib.libusb_free_transfer(t)
        self._spare.clear()


_LIBUSB_ERRNO = {-1: errno.EIO, -3: errno.EACCES, -4: errno.ENODEV, -6: errno.EBUSY,
                 -7: errno.ETIMEDOUT, -9: errno.EPIPE, -11: errno.ENOMEM}


def _usb_error(rc: int, what: str) -> usb.core.USBError:
    return usb.core.USBError(f"libusb error {rc} while {what}", rc, _LIBUSB_ERRNO.get(rc, errno.EIO))
