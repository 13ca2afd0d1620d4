"""A TCP relay that delays every byte by a fixed time each way: link delay where the kernel has no tc netem (the
Zenoh site tests and automotive bench zenoh shape their link with it, tc tbf and nftables).

    python -m automotive.tools.support.delay_relay --listen 127.0.0.1:17447 --target 10.234.0.1:7447 --delay-ms 25

Each connection accepted on --listen is relayed to --target; what arrives on either side is passed on --delay-ms
after it arrived, in order (a chunk waits for its time, so a stream keeps its rate and gains the delay). The bytes
are not looked at: a TLS session passes through unchanged. Prints "relay ready" once it listens; stops on SIGTERM
or Ctrl-C.
"""

from __future__ import annotations

import argparse
import asyncio
import signal
import sys
import time

from automotive.bus.cli import ArgumentParser

PROG = "python -m automotive.tools.support.delay_relay"


def host_port(text: str) -> tuple[str, int]:
    host, _, port = text.rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) <= 65535:
        raise argparse.ArgumentTypeError(f"'{text}' is not HOST:PORT")
    return host, int(port)


async def pipe(reader: asyncio.StreamReader, writer: asyncio.StreamWriter, delay_s: float) -> None:
    queue: asyncio.Queue[tuple[float, bytes]] = asyncio.Queue()

    async def receive() -> None:
        while True:
            chunk = await reader.read(65536)
            await queue.put((time.monotonic() + delay_s, chunk))
            if not chunk:
                return

    async def send() -> None:
        while True:
            due, chunk = await queue.get()
            wait = due - time.monotonic()
            if wait > 0:
                await asyncio.sleep(wait)
            if not chunk:
                writer.close()
                return
            writer.write(chunk)
            await writer.drain()

    try:
        await asyncio.gather(receive(), send())
    except (ConnectionError, OSError):
        writer.close()


async def relay(listen: tuple[str, int], target: tuple[str, int], delay_s: float) -> None:
    async def on_connection(client_reader: asyncio.StreamReader, client_writer: asyncio.StreamWriter) -> None:
        try:
            server_reader, server_writer = await asyncio.open_connection(*target)
        except OSError:
            client_writer.close()
            return
        await asyncio.gather(pipe(client_reader, server_writer, delay_s), pipe(server_reader, client_writer, delay_s),
                             return_exceptions=True)

    server = await asyncio.start_server(on_connection, *listen)
    stop = asyncio.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        asyncio.get_running_loop().add_signal_handler(sig, stop.set)
    print("relay ready", flush=True)
    async with server:
        await stop.wait()


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--listen", type=host_port, required=True, metavar="HOST:PORT", help="where to accept")
    parser.add_argument("--target", type=host_port, required=True, metavar="HOST:PORT",
                        help="where each accepted connection is relayed to")
    parser.add_argument("--delay-ms", type=float, default=25.0, help="delay each way, ms (default 25)")
    args = parser.parse_args(argv)
    if args.delay_ms < 0:
        parser.error(f"--delay-ms {args.delay_ms:g}: expected 0 or more")
    try:
        asyncio.run(relay(args.listen, args.target, args.delay_ms / 1000))
    except OSError as error:  # the listen address is taken or not this host's
        print(f"{PROG}: --listen {args.listen[0]}:{args.listen[1]}: {error.strerror or error}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
