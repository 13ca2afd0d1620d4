"""Cyclone's C tool, ddsperf, as the benchmarks' reference: what the same flow costs without Python."""

from __future__ import annotations

import os
import shutil
import time

from automotive.tools.support.children import Child, stop_all, thread_cpu_by_name

# ddsperf 0.10 (Debian's) does not know every element of our NetworkConfig's XML: a plain loopback configuration.
DDSPERF_URI = ('<General><Interfaces><NetworkInterface name="lo"/></Interfaces><AllowMulticast>false</AllowMulticast>'
               '</General><Discovery><ParticipantIndex>auto</ParticipantIndex><Peers><Peer address="127.0.0.1"/>'
               '</Peers></Discovery>')
SETTLE_S = 2.0  # discovery and the first samples, left out of the window


def subscriber_cpu(size: int, rate_hz: int, seconds: float, domain: int) -> dict[str, float] | None:
    """CPU of ``ddsperf sub`` (WaitSet, as the applications take) per sample, in microseconds by thread name, while
    ``ddsperf pub`` writes ``rate_hz`` samples a second of ``size`` bytes over loopback; None without ddsperf."""
    ddsperf = shutil.which("ddsperf")
    if ddsperf is None:
        return None
    env = dict(os.environ, CYCLONEDDS_URI=DDSPERF_URI)
    duration = str(round(SETTLE_S + seconds + 5))
    sub = Child("ddsperf-sub", [ddsperf, "-i", str(domain), "-D", duration, "sub", "waitset"], env=env)
    pub = Child("ddsperf-pub", [ddsperf, "-i", str(domain), "-D", duration, "pub", f"{rate_hz}Hz", "size",
                                str(size)], env=env)
    try:
        time.sleep(SETTLE_S)  # discovery: ddsperf prints nothing to wait on before its first second of figures
        before = thread_cpu_by_name([sub.pid])
        time.sleep(seconds)  # the measuring window
        after = thread_cpu_by_name([sub.pid])
    finally:
        stop_all([pub, sub], timeout=5)
    samples = rate_hz * seconds
    return {name: 1e6 * (after.get(name, 0.0) - used) / samples for name, used in before.items()}
