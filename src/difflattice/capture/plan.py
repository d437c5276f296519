"""What a scan covers: its points, the ones still missing and the runs of them to request.
Nothing here imports JAX."""

from __future__ import annotations

from dataclasses import dataclass

from . import protocol as P


@dataclass(frozen=True)
class ScanPlan:
    """One scan in the rig's integer units: ``n`` points at ``start + seq * step``.

    Lobe: ``start``/``step`` in mdeg. Wave: ``start``/``step`` are ``x0``/``dx`` in um and ``z_um``
    is the line's distance from the face.
    """

    kind: str
    n: int
    start: int
    step: int
    n_avg: int
    cycles: int
    freq_hz: int
    z_um: int = 0

    @classmethod
    def lobe(
        cls, start_deg: float, stop_deg: float, step_deg: float, n_avg: int, cycles: int, freq_hz: float
    ) -> ScanPlan:
        start, stop, step = (round(v * 1000) for v in (start_deg, stop_deg, step_deg))
        return cls("lobe", _count(start, stop, step, "deg", 1000), start, step, n_avg, cycles, round(freq_hz))

    @classmethod
    def wave(
        cls, x0_m: float, x1_m: float, dx_m: float, z_m: float, n_avg: int, cycles: int, freq_hz: float
    ) -> ScanPlan:
        x0, x1, dx = (round(v * 1e6) for v in (x0_m, x1_m, dx_m))
        n = _count(x0, x1, dx, "m", 1e6)
        return cls("wave", n, x0, dx, n_avg, cycles, round(freq_hz), round(z_m * 1e6))

    def __post_init__(self) -> None:
        for name in ("n_avg", "cycles", "freq_hz"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if self.kind == "wave" and self.z_um <= 0:
            raise ValueError(f"z_m must be > 0, got {self.z_um * 1e-6}")

    def command(self, scan: int, first: int, n: int) -> P.Lobe | P.Wave:
        """The scan command for points ``first..n-1``."""
        if self.kind == "lobe":
            return P.Lobe(scan, first, n, self.start, self.step, self.n_avg, self.cycles, self.freq_hz)
        return P.Wave(scan, first, n, self.start, self.step, self.z_um, self.n_avg, self.cycles, self.freq_hz)

    def matches(self, msg: P.Lob | P.Wav) -> bool:
        """Whether a point line is of this scan's kind and at its seq's position."""
        if self.kind == "lobe":
            return isinstance(msg, P.Lob) and msg.angle_mdeg == self.start + msg.seq * self.step
        return isinstance(msg, P.Wav) and msg.x_um == self.start + msg.seq * self.step and msg.z_um == self.z_um

    def header(self) -> dict[str, int]:
        """The scan's keys of a capture file header."""
        keys = ("start_mdeg", "step_mdeg") if self.kind == "lobe" else ("x0_um", "dx_um")
        head = {"n_points": self.n, keys[0]: self.start, keys[1]: self.step}
        if self.kind == "wave":
            head["z_um"] = self.z_um
        return head | {"n_avg": self.n_avg, "cycles": self.cycles, "freq_hz": self.freq_hz}

    def next_request(self, missing: list[int]) -> tuple[int, int]:
        """``(first_seq, n)`` for the next command: the first run of missing points, or the rest
        of the scan from the first missing point when everything after it is missing."""
        first = end = missing[0]
        for s in missing[1:]:
            if s != end + 1:
                break
            end = s
        return first, (self.n if end == self.n - 1 else end + 1)


def _count(start: int, stop: int, step: int, unit: str, scale: float) -> int:
    if step == 0 or (stop - start) * step < 0 or (stop - start) % step:
        raise ValueError(
            f"the scan from {start / scale} to {stop / scale} {unit} must be a whole, positive number "
            f"of steps of {step / scale} {unit}"
        )
    return (stop - start) // step + 1
