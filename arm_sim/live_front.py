"""The live view's front door: one port for both names of the Foxglove WebSocket protocol.

foxglove-sdk 0.30.3 (the live view's server, :class:`arm_sim.live.Bridge`) completes a
WebSocket handshake only when the client offers the subprotocol ``foxglove.sdk.v1``
(hard-coded in its Rust handshake; ``start_server`` has no option for it) and answers
anything else with HTTP 400 and a bare ``handshake failed`` in the log. Stock clients --
``@foxglove/ws-protocol``'s ``FoxgloveClient``, Lichtblick, PlotJuggler -- offer the
protocol's original name ``foxglove.websocket.v1``. Both names denote the same protocol
(the SDK renamed it without changing a message; Lichtblick's support for the new name
is a second string in its list), so the difference is one header.

:class:`Front` listens on the public address, the SDK on a loopback port of its own. For
each connection it reads the client's HTTP upgrade request (stdlib asyncio, no extra
package) and

* forwards it unchanged when it offers an SDK name (``foxglove.sdk.*``);
* offering ``foxglove.websocket.v1`` only: forwards it with ``foxglove.sdk.v1`` offered
  instead, and rewrites the SDK's ``101`` answer to name ``foxglove.websocket.v1``, the
  name the client asked for (a browser closes a connection whose subprotocol it did not
  offer);
* otherwise (no subprotocol, none of these, not a WebSocket upgrade) answers ``400`` itself
  with the reason in the body and reports it (``on_refusal``): which subprotocols were
  offered and which are accepted. A handshake the SDK refuses anyway is reported too, with
  its status and body.

After the handshake it copies bytes both ways unchanged: the frames (masked by the client,
unmasked by the server), ``Sec-WebSocket-Accept`` (a function of the client's key alone)
and any extension both ends negotiated (permessage-deflate) pass through as they are.
Nothing is parsed or buffered beyond what the sockets hand over; reading pauses on one side
while the other's write buffer is full, so a slow client slows only its own connection
(the SDK then drops its oldest data-plane messages, as without the front).

The front runs its own event loop in a daemon thread; :meth:`Front.stop` closes it and
every relayed connection.
"""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Callable
from dataclasses import dataclass

#: The name foxglove-sdk accepts, and the protocol's original name stock clients offer.
SDK_SUBPROTOCOL = 'foxglove.sdk.v1'
LEGACY_SUBPROTOCOL = 'foxglove.websocket.v1'
ACCEPTED = (SDK_SUBPROTOCOL, LEGACY_SUBPROTOCOL)
#: Longest request or response head (request line and headers) read before refusing.
MAX_HEAD = 16 * 1024
#: How long a client has to send its upgrade request [s, wall].
HANDSHAKE_TIMEOUT = 10.0
_PROTOCOL_HEADER = 'sec-websocket-protocol'


# ---------------------------------------------------------------------- the handshake
def _headers(head: bytes) -> tuple[str, list[tuple[str, str]]]:
    """(start line, [(name, value)]) of an HTTP head (``\\r\\n\\r\\n`` included or not)."""
    lines = head.decode('latin-1').split('\r\n')
    out = []
    for line in lines[1:]:
        if line:
            name, _, value = line.partition(':')
            out.append((name.strip(), value.strip()))
    return lines[0], out


def _head(start: str, headers: list[tuple[str, str]]) -> bytes:
    return ('\r\n'.join([start] + [f'{k}: {v}' for k, v in headers]) + '\r\n\r\n').encode(
        'latin-1')


def offered_subprotocols(headers: list[tuple[str, str]]) -> list[str]:
    """The subprotocols a request offers, in order (every ``Sec-WebSocket-Protocol``
    header, comma-separated)."""
    return [p.strip() for k, v in headers if k.lower() == _PROTOCOL_HEADER
            for p in v.split(',') if p.strip()]


@dataclass(frozen=True)
class Upgrade:
    """What to do with a client's upgrade request: ``head`` goes to the SDK; ``legacy``:
    the answer's subprotocol is renamed back to ``foxglove.websocket.v1``; ``offered``:
    what the client offered."""

    head: bytes
    legacy: bool
    offered: tuple[str, ...]


def upgrade_request(head: bytes) -> Upgrade | str:
    """The request to forward to the SDK for a client's request ``head``, or why it is
    refused (a str: what was offered and what is accepted)."""
    start, headers = _headers(head)
    parts = start.split(' ')
    upgrade = any(k.lower() == 'upgrade' and v.lower() == 'websocket' for k, v in headers)
    if len(parts) != 3 or parts[0] != 'GET' or not upgrade:
        return (f'not a WebSocket upgrade request ({start[:80]!r}); the live view speaks the '
                f'Foxglove WebSocket protocol ({", ".join(ACCEPTED)})')
    offered = offered_subprotocols(headers)
    accepted = ', '.join(ACCEPTED)
    if not offered:
        return f'offered no WebSocket subprotocol (accepted: {accepted})'
    if any(p.startswith('foxglove.sdk.') for p in offered):
        return Upgrade(head, False, tuple(offered))
    if LEGACY_SUBPROTOCOL in offered:
        rest = [(k, v) for k, v in headers if k.lower() != _PROTOCOL_HEADER]
        return Upgrade(_head(start, rest + [('Sec-WebSocket-Protocol', SDK_SUBPROTOCOL)]),
                       True, tuple(offered))
    return f'offered subprotocols {", ".join(offered)}; accepted: {accepted}'


def upgrade_response(head: bytes, legacy: bool) -> tuple[int, bytes]:
    """(status, head to send the client) of the SDK's answer ``head``: with ``legacy``, a
    ``101``'s subprotocol ``foxglove.sdk.v1`` is named ``foxglove.websocket.v1``. A status
    that cannot be read is 0."""
    start, headers = _headers(head)
    try:
        status = int(start.split(' ')[1])
    except (IndexError, ValueError):
        status = 0
    if not (legacy and status == 101):
        return status, head
    return status, _head(start, [(k, LEGACY_SUBPROTOCOL if k.lower() == _PROTOCOL_HEADER
                                  and v == SDK_SUBPROTOCOL else v) for k, v in headers])


def refusal_response(reason: str, status: int = 400) -> bytes:
    """The HTTP answer to a refused handshake, the reason in its body."""
    body = (reason + '\n').encode()
    phrase = {400: 'Bad Request', 431: 'Request Header Fields Too Large',
              502: 'Bad Gateway'}.get(status, 'Error')
    return (f'HTTP/1.1 {status} {phrase}\r\nContent-Type: text/plain; charset=utf-8\r\n'
            f'Content-Length: {len(body)}\r\nConnection: close\r\n\r\n').encode() + body


# ---------------------------------------------------------------------- relaying
class _Side(asyncio.Protocol):
    """One socket of a relayed connection: what it receives goes to ``peer``'s socket;
    its write buffer filling pauses reading on the peer."""

    def __init__(self, front: Front) -> None:
        self.front = front
        self.transport: asyncio.Transport | None = None
        self.peer: _Side | None = None
        self.head = bytearray()
        self.relaying = False

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]
        self.front.transports.add(transport)  # type: ignore[arg-type]

    def connection_lost(self, exc: Exception | None) -> None:
        if self.transport is not None:
            self.front.transports.discard(self.transport)
        if self.peer is not None and self.peer.transport is not None:
            self.peer.transport.close()  # after what it still has to send

    def eof_received(self) -> bool:
        return False  # close: WebSocket ends with close frames, not half-closed sockets

    def pause_writing(self) -> None:
        if self.peer is not None and self.peer.transport is not None:
            self.peer.transport.pause_reading()

    def resume_writing(self) -> None:
        if self.peer is not None and self.peer.transport is not None:
            self.peer.transport.resume_reading()

    def data_received(self, data: bytes) -> None:
        """Relay once relaying; before that, gather the HTTP head and hand it, with the
        bytes after it, to :meth:`head_received` (:meth:`head_too_long` if it grows past
        :data:`MAX_HEAD` without ending)."""
        if self.relaying:
            self._send_peer(data)
            return
        self.head += data
        end = self.head.find(b'\r\n\r\n')
        if end < 0:
            if len(self.head) > MAX_HEAD:
                self.head_too_long()
            return
        head, rest = bytes(self.head[:end + 4]), bytes(self.head[end + 4:])
        self.head.clear()
        self.relaying = True  # from now on (more than the head): to the peer
        self.head_received(head, rest)

    def head_received(self, head: bytes, rest: bytes) -> None:
        raise NotImplementedError

    def head_too_long(self) -> None:
        raise NotImplementedError

    def _send_peer(self, data: bytes | bytearray) -> None:
        if self.peer is not None and self.peer.transport is not None:
            self.peer.transport.write(data)

    def peer_name(self) -> str:
        t = self.transport
        addr = t.get_extra_info('peername') if t is not None else None
        return f'{addr[0]}:{addr[1]}' if addr else 'unknown'


class _ClientSide(_Side):
    """A client's socket: its upgrade request first, then relayed bytes."""

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        super().connection_made(transport)
        self.timer = self.front.loop.call_later(HANDSHAKE_TIMEOUT, self._timed_out)
        self.client = self.peer_name()

    def connection_lost(self, exc: Exception | None) -> None:
        self.timer.cancel()
        super().connection_lost(exc)

    def _timed_out(self) -> None:
        if not self.relaying and self.transport is not None and self.peer is None:
            self._refuse(f'sent no complete upgrade request within {HANDSHAKE_TIMEOUT:g} s')

    def _refuse(self, reason: str, status: int = 400) -> None:
        self.front.report(f'WebSocket handshake from {self.client} refused: {reason}')
        if self.transport is not None:
            self.transport.write(refusal_response(reason, status))
            self.transport.close()

    def head_too_long(self) -> None:
        self._refuse(f'upgrade request longer than {MAX_HEAD} bytes', 431)

    def head_received(self, head: bytes, rest: bytes) -> None:
        """The client's upgrade request: refused, or rewritten and sent to the SDK."""
        self.timer.cancel()
        decision = upgrade_request(head)
        if isinstance(decision, str):
            self.relaying = False
            self._refuse(decision)
            return
        assert self.transport is not None
        self.transport.pause_reading()  # until the SDK's socket is connected
        self.front.loop.create_task(self._connect(decision, rest))

    async def _connect(self, up: Upgrade, rest: bytes) -> None:
        try:
            _, server = await self.front.loop.create_connection(
                lambda: _ServerSide(self.front, self, up), self.front.backend_host,
                self.front.backend_port)
        except OSError as exc:
            self._refuse(f'the Foxglove server on {self.front.backend_host}:'
                         f'{self.front.backend_port} cannot be reached: {exc}', 502)
            return
        if self.transport is None or self.transport.is_closing():
            server.transport.close()  # type: ignore[union-attr]
            return
        self.peer = server
        server.transport.write(up.head + rest)  # type: ignore[union-attr]
        self.transport.resume_reading()


class _ServerSide(_Side):
    """The socket to the SDK's server: its answer to the upgrade first, then relayed."""

    def __init__(self, front: Front, client: _ClientSide, up: Upgrade) -> None:
        super().__init__(front)
        self.peer = client
        self.up = up

    def head_too_long(self) -> None:
        self._send_peer(self.head)  # not an answer this front understands: passed on
        self.head.clear()
        self.relaying = True

    def head_received(self, head: bytes, rest: bytes) -> None:
        """The SDK's answer to the upgrade: renamed back for a legacy client, relayed."""
        status, head = upgrade_response(head, self.up.legacy)
        self._send_peer(head + rest)
        if status != 101:
            body = rest.decode('utf-8', 'replace').strip()
            client = self.peer.client if isinstance(self.peer, _ClientSide) else '?'
            self.front.report(f'WebSocket handshake from {client} refused by the Foxglove '
                              f'server: HTTP {status} {body!r} (offered subprotocols: '
                              f'{", ".join(self.up.offered)})')


class Front:
    """Listen on ``host``:``port`` (0: a free one, :attr:`port`) and relay each client to
    the Foxglove server on ``backend_host``:``backend_port`` (see the module docstring).
    ``on_refusal(text)`` is called (from the front's thread) for each refused handshake.

    Raises
    ------
    OSError
        The address cannot be bound.
    """

    def __init__(self, host: str, port: int, backend_port: int,
                 on_refusal: Callable[[str], None] | None = None,
                 backend_host: str = '127.0.0.1') -> None:
        self.backend_host = backend_host
        self.backend_port = backend_port
        self.on_refusal = on_refusal
        self.transports: set[asyncio.Transport] = set()
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, name='live-front',
                                       daemon=True)
        self.thread.start()
        try:
            self.server = asyncio.run_coroutine_threadsafe(
                self._listen(host, port), self.loop).result(30)
        except BaseException:
            self._end_loop()
            raise
        self.port = int(self.server.sockets[0].getsockname()[1])

    async def _listen(self, host: str, port: int) -> asyncio.Server:
        return await self.loop.create_server(lambda: _ClientSide(self), host, port)

    def report(self, text: str) -> None:
        if self.on_refusal is not None:
            try:
                self.on_refusal(text)
            except Exception:  # a report must not break the relay
                pass

    async def _close(self) -> None:
        self.server.close()
        for t in list(self.transports):
            t.abort()

    def stop(self) -> None:
        """Stop listening and close every relayed connection."""
        if self.loop.is_closed():
            return
        try:
            asyncio.run_coroutine_threadsafe(self._close(), self.loop).result(10)
        finally:
            self._end_loop()

    def _end_loop(self) -> None:
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(10)
        if not self.thread.is_alive():
            self.loop.close()
