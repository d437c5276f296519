"""Draw the reference rig's wiring diagram (docs/images/rig_wiring.png) from the pin map of
``firmware/rig_firmware/src/teensy41/teensy41_hal.h``.

Run: ``python firmware/tools/wiring_diagram.py [OUT.png]``.
"""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.patches import FancyBboxPatch  # noqa: E402

OUT = Path(__file__).resolve().parents[2] / "docs" / "images" / "rig_wiring.png"

COLOURS = {"mcu": "#cfe2ff", "motion": "#ffe5b4", "analog": "#d8f0d2", "power": "#f6d0d0", "other": "#eeeeee"}


def box(ax, x, y, w, h, title, lines=(), kind="other"):
    ax.add_patch(
        FancyBboxPatch((x, y), w, h, boxstyle="round,pad=0.02,rounding_size=0.08", fc=COLOURS[kind], ec="#333", lw=1.2)
    )
    ax.text(x + w / 2, y + h - 0.12, title, ha="center", va="top", fontsize=9.5, weight="bold")
    for i, line in enumerate(lines):
        ax.text(x + w / 2, y + h - 0.42 - 0.24 * i, line, ha="center", va="top", fontsize=7.5)


def wire(ax, pts, label="", colour="#333", at=0.5, dy=0.07, ls="-"):
    xs, ys = zip(*pts, strict=True)
    ax.plot(xs, ys, color=colour, lw=1.3, ls=ls, solid_capstyle="round")
    if label:
        i = max(0, min(len(pts) - 2, int(at * (len(pts) - 1))))
        (x0, y0), (x1, y1) = pts[i], pts[i + 1]
        ax.text((x0 + x1) / 2, (y0 + y1) / 2 + dy, label, ha="center", va="bottom", fontsize=7, color=colour)


def draw(out: Path = OUT) -> Path:
    fig, ax = plt.subplots(figsize=(15, 9.5))
    ax.set_xlim(0, 15)
    ax.set_ylim(0, 9.5)
    ax.axis("off")
    ax.set_title(
        "difflattice reference rig: wiring (Teensy 4.1; pins as in teensy41_hal.h)", fontsize=12, weight="bold"
    )

    box(ax, 0.3, 7.4, 2.0, 1.3, "Lab PC", ["difflattice capture", "USB serial, protocol v1"], "other")
    box(
        ax,
        4.3,
        3.3,
        2.6,
        5.0,
        "Teensy 4.1",
        ["i.MX RT1062, 600 MHz", "Cortex-M7 + FPU", "ADC1: 12 bit", "USB device"],
        "mcu",
    )
    wire(ax, [(2.3, 8.0), (4.3, 8.0)], "USB (power + data)", "#1f4e9c")

    # motion: three axes
    names = [
        ("Turntable (90:1 worm)", 2, 3, 4, 5),
        ("Stage X (SFU1204)", 6, 7, 8, 9),
        ("Stage Z (SFU1204)", 24, 25, 26, 27),
    ]
    for i, (name, step, direction, en, home) in enumerate(names):
        y = 7.6 - 1.55 * i
        box(ax, 8.6, y - 0.55, 1.9, 1.2, "TMC2209 driver", ["StepStick, 16 usteps", "VM 24 V"], "motion")
        box(ax, 11.4, y - 0.55, 1.9, 1.2, "NEMA 17 motor", ["17HS4401, 1.8 deg", name], "motion")
        box(ax, 13.6, y - 0.35, 1.25, 0.8, "home switch", ["NC to GND"], "motion")
        wire(ax, [(6.9, y + 0.35), (8.6, y + 0.35)], f"STEP {step}  DIR {direction}  EN {en}", "#9c5b00")
        wire(ax, [(10.5, y + 0.05), (11.4, y + 0.05)], "A1 A2 B1 B2", "#9c5b00")
        wire(ax, [(6.9, y - 0.2), (7.6, y - 0.2), (7.6, y - 0.75), (14.2, y - 0.75), (14.2, y - 0.35)],
             f"pin {home} (INPUT_PULLUP; HIGH = at switch / broken wire)", "#9c5b00", at=0.6, dy=-0.2)  # fmt: skip

    # transducer drive
    box(ax, 8.6, 1.75, 1.9, 1.1, "TC4427A", ["dual MOSFET driver", "VDD 12 V"], "power")
    box(ax, 11.4, 1.75, 1.9, 1.1, "transducer", ["under test (e.g.", "MA40S4S, 40 kHz)"], "other")
    wire(
        ax,
        [(6.9, 3.55), (7.9, 3.55), (7.9, 2.45), (8.6, 2.45)],
        "DRIVE_A 28, DRIVE_B 29 (antiphase)",
        "#a11",
        at=0.0,
        dy=0.05,
    )
    wire(ax, [(10.5, 2.3), (11.4, 2.3)], "", "#a11")
    ax.text(10.95, 1.55, "24 Vpp burst", ha="center", fontsize=7, color="#a11")

    # microphone front end
    box(
        ax, 0.2, 0.25, 1.9, 1.35, "microphones", ["SPU0410LR5H-QB", "CH0 lobe, CH1 wave", "(MEMS, to 80 kHz)"], "analog"
    )
    box(
        ax,
        2.5,
        0.25,
        2.2,
        1.35,
        "preamp + anti-alias",
        ["OPA2836, gain 2", "4th-order Butterworth", "fc 150 kHz, bias 1.65 V"],
        "analog",
    )
    box(ax, 5.1, 0.25, 2.0, 1.35, "PGA MCP6S22", ["2 inputs, gain 1..32", "SPI: CS 10, MOSI 11,", "SCK 13"], "analog")
    wire(ax, [(2.1, 0.9), (2.5, 0.9)], "", "#2a7a2a")
    wire(ax, [(4.7, 0.9), (5.1, 0.9)], "", "#2a7a2a")
    wire(ax, [(7.1, 0.9), (7.5, 0.9), (7.5, 3.8), (6.9, 3.8)], "", "#2a7a2a")
    ax.text(7.6, 1.45, "A0 (pin 14), 0-3.3 V", fontsize=7, color="#2a7a2a")
    wire(ax, [(6.1, 1.6), (6.1, 3.3)], "SPI", "#2a7a2a", dy=0.0)

    # environment and power
    box(ax, 0.3, 4.4, 2.0, 1.1, "TMP117", ["air temperature", "+-0.1 degC, I2C 0x48"], "analog")
    wire(ax, [(2.3, 4.95), (4.3, 4.95)], "SDA 18, SCL 19", "#2a7a2a")
    box(
        ax,
        0.3,
        2.2,
        2.0,
        1.4,
        "24 V 5 A PSU",
        ["Mean Well LRS-150-24", "-> drivers VM", "-> 12 V buck -> TC4427"],
        "power",
    )
    wire(ax, [(2.3, 2.6), (3.6, 2.6), (3.6, 1.9), (8.0, 1.9), (8.0, 2.1), (8.6, 2.1)], "12 V", "#a11", at=0.5, dy=-0.22)
    wire(ax, [(2.3, 3.2), (3.9, 3.2), (3.9, 9.05), (9.55, 9.05), (9.55, 8.25)], "24 V to each driver's VM (and GND)",
         "#a11", at=0.55, dy=0.05, ls="--")  # fmt: skip
    ax.text(
        0.3, 6.55,
        "Grounds: one star point at the PSU; analog ground of the\nfront end joins it at the Teensy's AGND only.\n"
        "Teensy 4.1 pins are 3.3 V only (not 5 V tolerant).",
        fontsize=7.5, va="top",
    )  # fmt: skip
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return out


if __name__ == "__main__":
    print(draw(Path(sys.argv[1]) if len(sys.argv) > 1 else OUT))
