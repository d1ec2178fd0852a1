"""The shims on the real serial drivers: the 8250 (QEMU's 16550, /dev/ttyS1) and ftdi_sio
(QEMU's FTDI FT232 behind xHCI, /dev/ttyUSB0), in one QEMU guest per case group, against the
simulator (tests/kernel/bed.py; docs/wiring.md "What the drivers allow").

    test_serial.py GROUP BUILD_DIR GUEST_PROGRAM
GROUP drivers: the device traffic (RTU, ASCII, RTU without CRC), the bauds against QEMU's trace, Direction
'KERNEL' refused, the latency in force. GROUP rts: Direction 'RTS' on a paced line, the RTS
edges against the frame's bits in QEMU's trace.
Exit 0 when every check holds, 1 on a failed check, 77 (skipped) without QEMU or the kernel.
"""
import os
import statistics
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bed import Bed, Port, Skip, skip_or_fail  # noqa: E402

USB_MODULES = ["usb-common", "usbcore", "xhci-hcd", "xhci-pci", "usbserial", "ftdi_sio"]
DEVICES = ("--baud 9600 --format 8N2 --device mvd94:1:SV=100.0,DP=1 --device vd:2 "
           "--device fdc100:3:SP1=150.0 --device mts9:4:framing=rtu --device mts9:5:framing=ascii "
           "--device mts9:6:framing=nocrc")
# the first word each read must show: the values DEVICES gives the simulator (MV-D94 SV 100.0
# with one decimal; FDC SP1 150.0: M = A * 10 + 19999)
FIRST = {"mvd94": 1000, "fdc100": 21499}
BAUDS = [9600, 14400, 19200, 28800, 38400, 57600, 76800, 115200]
TOLERANCE = 0.01  # c_shims/src/mbfb_baud.c, MBFB_BAUD_TOLERANCE_PERMILLE
S1, U0 = "/dev/ttyS1", "/dev/ttyUSB0"

failures = []


def check(ok, what):
    print(("ok    " if ok else "FAIL  ") + what)
    if not ok:
        failures.append(what)


def results(output, what):
    """The program's RESULT lines of one kind as dicts (with 'port')."""
    out = []
    for line in output.splitlines():
        parts = line.split()
        if len(parts) >= 3 and parts[0] == "RESULT" and parts[1] == what:
            d = {"port": parts[2]}
            for kv in parts[3:]:
                k, _, v = kv.partition("=")
                d[k] = int(v) if v.lstrip("-").isdigit() else v
            out.append(d)
    return out


def window(run, start, end):
    """Trace events between two marks (host times)."""
    t0 = next(t for t, m in run.marks if m == start)
    t1 = next((t for t, m in run.marks if m == end and t > t0), float("inf"))
    return [e for e in run.trace if t0 <= e[0] <= t1]


def until_next_mark(run, start):
    """Trace events from a mark to the next one."""
    marks = sorted(run.marks)
    i = next(k for k, (_, m) in enumerate(marks) if m == start)
    t1 = marks[i + 1][0] if i + 1 < len(marks) else float("inf")
    return [e for e in run.trace if marks[i][0] <= e[0] <= t1]


def check_bauds(run, port, rate_of):
    """The port's bauds: what the driver programmed (rate_of(trace events)) is what was asked
    (TOLERANCE), or ErrorID 14 and the shims' one line naming the rate it would run at; the
    simulator heard bytes exactly when the open worked."""
    for d in results(run.output, "bauds"):
        if d["port"] != port:
            continue
        asked = d["asked"]
        rate = rate_of(until_next_mark(run, f"baud {asked} {port}"))
        ok_rate = rate is not None and abs(rate - asked) <= asked * TOLERANCE
        said = [ln for ln in run.output.splitlines()
                if ln.startswith(f"mbfb: {port}: {asked} baud asked")]
        if d["rc"] == 0:
            check(ok_rate, f"{port} {asked}: the driver programmed {rate}, within 1 %")
        else:
            check(d["rc"] == 14 and not ok_rate and len(said) == 1 and
                  f"would run at {rate} " in said[0],
                  f"{port} {asked}: ErrorID {d['rc']}, the driver programmed {rate}, "
                  f"the shims said: {said}")
        check(d["sim_heard"] == 0 if d["rc"] else d["sim_heard"] > 0,
              f"{port} {asked}: the simulator heard {d['sim_heard']} bytes")
        err = f"{(rate - asked) * 100 / asked:+.2f} %" if rate else "-"
        print(f"      {port} asked {asked}: programmed {rate} ({err}), ErrorID {d['rc']}")


def check_rts_timing(port, lead, late, before, after, ch):
    """RTS around each frame (lead: asserted before its first byte, late: released after its
    last bit, us): at least DirBeforeUs before, never before the last bit, and released within
    one character + DirAfterUs of it (the median: QEMU's vCPU thread is now and then not
    scheduled for milliseconds on a loaded machine, both edges then move; the maximum is
    printed, not asserted; tcdrain's jiffy, 9 ms late at 9600, is far outside). The guest's
    timers under TCG are late by an amount of their own, measured on the same pulses: the lead
    is one sleep of DirBeforeUs, its median excess over that is the guest's oversleep in this
    run; the release path sleeps twice (until the frame's wire time is up, then DirAfterUs), so
    the slack is twice that oversleep, at least TCG_SLACK_US."""
    if not late:
        return
    print(f"      {port} RTS: before the first byte {min(lead):.0f}..{max(lead):.0f} us "
          f"(DirBeforeUs {before}); released {min(late):.0f}..{max(late):.0f} us after the "
          f"frame's last bit (one character {ch:.0f} us + DirAfterUs {after})")
    check(min(lead) >= before, f"{port} RTS asserted at least DirBeforeUs before the first byte")
    check(min(late) >= 0, f"{port} RTS never released before the frame's last bit")
    median = statistics.median_high(late)
    oversleep = max(0.0, statistics.median_high(lead) - before)
    slack = max(TCG_SLACK_US, 2 * oversleep)
    check(median <= ch + after + slack,
          f"{port} RTS released within one character + DirAfterUs of the last bit, median "
          f"{median:.0f} us (+{slack:.0f} us for the guest's timers under TCG: twice the "
          f"{oversleep:.0f} us its DirBeforeUs sleep overslept, at least {TCG_SLACK_US})")


def programmed_rate(events, port):
    """The rate the driver programmed for our 8N2 line in these events (the port's close
    programs the next open's default, 9600 8N1, afterwards): the 16550's divisor
    (serial_update_parameters with 2 stop bits), or the FTDI's (usb_serial_set_baud while
    the chip's data format is 8N2: FTDI_SIO_SET_DATA, request 0x4004, value 0x1008)."""
    rate, ours = None, False
    for _, name, f in events:
        if port == S1 and name == "serial_update_parameters" and f.get("stop") == 2:
            rate = f.get("baudrate")
        elif port == U0 and name == "usb_serial_handle_control" and \
                f.get("control") == 0x4004:
            ours = f.get("value") == 0x1008
        elif port == U0 and name == "usb_serial_set_baud" and ours:
            rate = f.get("rate")
    return rate


def group_drivers(bed, program):
    # latency first: ftdi_sio keeps ASYNC_LOW_LATENCY across opens once the shims set it
    steps = [f"latency:{S1}:0", f"latency:{U0}:1", f"devices:{S1}:0", f"devices:{U0}:1",
             f"bauds:{S1}:0:{','.join(map(str, BAUDS))}",
             f"bauds:{U0}:1:{','.join(map(str, BAUDS))}",
             f"kernel:{S1}:0", f"kernel:{U0}:1"]
    run = bed.boot(program, args=steps, modules=USB_MODULES,
                   ports=[Port("8250", DEVICES), Port("ftdi", DEVICES)])
    print(f"boot and run: {run.seconds:.1f} s, program exit {run.rc}")
    print(run.output)
    check(run.rc == 0, "the guest program ran to its end")
    # every device block's traffic, RTU and ASCII, on both drivers
    for port in (S1, U0):
        seen = {d["device"]: d for d in results(run.output, "devices") if d["port"] == port
                and "read" in d}
        for name in ("mvd94", "vd", "fdc100", "mts9-rtu", "mts9-ascii", "mts9-nocrc"):
            d = seen.get(name)
            check(d is not None and d["read"] == 0 and d["write"] == 0 and d["readback"] == 0
                  and d["back"] == d["asked"] and d["first"] == FIRST.get(name, d["first"]),
                  f"{port} {name}: read, set point Done, read back equal ({d})")
        pulled = [d for d in results(run.output, "devices") if d["port"] == port
                  and "pulled" in d]
        check(len(pulled) == 1 and pulled[0]["pulled"] in (1, 4) and pulled[0]["back"] == 0,
              f"{port} a device pulled fails its read (timeout/offline) and reads again when "
              f"back ({pulled})")
    # bauds: what the driver programmed is what was asked (1 %), or ErrorID 14 naming it
    for port in (S1, U0):
        check_bauds(run, port, lambda events, port=port: programmed_rate(events, port))
    # Direction KERNEL: the 8250 driver here and ftdi_sio have no RS-485 mode: ErrorID 15 and
    # nothing reached the simulator
    for port in (S1, U0):
        k = [d for d in results(run.output, "kernel") if d["port"] == port]
        check(len(k) == 1 and k[0]["rc"] == 15 and k[0]["sim_heard"] == 0,
              f"{port} Direction KERNEL: ErrorID 15, the simulator heard nothing ({k})")
    # latency in force once the port is open
    for d in results(run.output, "latency"):
        print(f"      {d['port']}: ASYNC_LOW_LATENCY {d['low_latency']}, latency_timer "
              f"{d['before_open_ms']} ms before the shims opened it, {d['latency_timer_ms']} ms "
              f"after")
        if d["port"] == U0:
            # before: what the chip reported at probe (QEMU's FT232 says 0 ms, a real one 16)
            check(d["read"] == 0 and d["low_latency"] == 1 and d["latency_timer_ms"] == 1,
                  f"{U0}: low latency in force after the shims opened it ({d})")


def char_us(baud, bits=11):
    return bits * 1e6 / baud


def group_rts(bed, program):
    baud, before, after, n = 9600, 500, 200, 12
    line = f"--baud {baud} --format 8N2 --device mvd94:1:SV=100.0,DP=1"
    steps = [f"rts:{S1}:0:{baud}:{before}:{after}:{n}", f"rts:{U0}:1:{baud}:{before}:{after}:{n}"]
    run = bed.boot(program, args=steps, modules=USB_MODULES,
                   ports=[Port("8250", line, "paced"), Port("ftdi", line, "paced")])
    print(f"boot and run: {run.seconds:.1f} s, program exit {run.rc}")
    print(run.output)
    check(run.rc == 0, "the guest program ran to its end")
    for d in results(run.output, "rts"):
        check(d["open"] == 0 and d["good"] == d["of"], f"{d['port']} RTS: every read good ({d})")
    ch = char_us(baud)
    wire = 8 * ch  # FC03 request, one register: 8 bytes
    # 8250: MCR (addr 4) bit 1 is RTS; THR (addr 0) writes are the request's bytes, entering
    # the FIFO at once (QEMU does not pace the UART); RBR reads (addr 0) the reply's
    ev = window(run, f"rts {S1}", f"rts-end {S1}")
    edges, rts_on, frame = [], None, []
    for t, name, f in ev:
        if name == "serial_write" and f.get("addr") == 4:
            on = bool(f.get("val", 0) & 2)
            if on and rts_on is None:
                rts_on, frame = t, []
            elif not on and rts_on is not None:
                edges.append((rts_on, frame, t))
                rts_on = None
        elif name == "serial_write" and f.get("addr") == 0 and rts_on is not None:
            frame.append(t)
    replies = [t for t, name, f in ev if name == "serial_read" and f.get("addr") == 0]
    check(len(edges) == n, f"{S1}: {len(edges)} RTS pulses for {n} requests")
    lead, late = [], []
    for on, frame, off in edges:
        if not frame:
            check(False, f"{S1}: an RTS pulse without a byte")
            continue
        first = frame[0]
        last_bit = first + wire / 1e6
        lead.append((first - on) * 1e6)
        late.append((off - last_bit) * 1e6)
        reply = next((t for t in replies if t > on), None)
        check(reply is None or reply > off, f"{S1}: RTS released before the reply was read")
    check_rts_timing(S1, lead, late, before, after, ch)
    # FTDI: RTS is a control transfer (FTDI_SIO_SET_MODEM_CTRL, request 0x4001: value bit 9
    # says RTS is set, bit 1 its level);
    # the data's bulk transfers are not traced: the pulse must last the frame's wire time and
    # DirBeforeUs at least, and end before the earliest reply (t3.5 + 1 ms turnaround later)
    ev = window(run, f"rts {U0}", f"rts-end {U0}")
    pulses, on = [], None
    for t, name, f in ev:
        v = f.get("value", 0)
        if name == "usb_serial_handle_control" and f.get("control") == 0x4001 and v & 0x0200:
            if v & 0x0002:
                on = t
            elif on is not None:
                pulses.append(t - on)
                on = None
    check(len(pulses) == n, f"{U0}: {len(pulses)} RTS pulses for {n} requests")
    if pulses:
        t35 = max(3.5 * ch, 44e6 / baud)
        print(f"      {U0}: RTS pulse {min(pulses) * 1e3:.2f}..{max(pulses) * 1e3:.2f} ms for a "
              f"{wire / 1e3:.2f} ms frame (DirBeforeUs {before}, DirAfterUs {after})")
        check(min(pulses) * 1e6 >= wire + before, f"{U0}: RTS held for the whole frame")
        # not asserted: how much later than the earliest reply (t3.5 + 1 ms after the last bit)
        # ftdi_sio lets RTS go. tcdrain waits for the write URB's completion and then reads
        # the chip's transmitter-empty bit with a control transfer; through QEMU's xHCI and
        # a paced line that took about 120 ms (docs/wiring.md, "What the drivers allow")
        print(f"      {U0}: earliest reply {(before + wire + t35 + 1000) / 1e3:.2f} ms after "
              f"RTS on: RTS {'released before it' if max(pulses) * 1e6 < before + wire + t35 + 1000 else 'still on then'}")


TCG_SLACK_US = 1000


def main():
    group, build, program = sys.argv[1:4]
    bed = Bed(build)
    try:
        bed.kernel()
    except Skip as e:
        skip_or_fail(str(e))
    {"drivers": group_drivers, "rts": group_rts}[group](bed, program)
    if failures:
        print(f"{len(failures)} check(s) failed")
        sys.exit(1)
    print("all checks passed")


if __name__ == "__main__":
    main()
