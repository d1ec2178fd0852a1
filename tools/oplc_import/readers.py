"""Readers of OpenPLC's Modbus master configurations, into one model (Device, Range).

* OpenPLC v3 "Slave Devices": mbconfig.cfg as webserver.py's generate_mbconfig() writes it and
  core/modbus_master.cpp's parseConfig() reads it (key = "value" lines, '#' comments), with the
  located addresses modbus_master.cpp assigns: each device in order takes the next discrete
  inputs (%IX100.0..), coils (%QX100.0..), input registers then holding registers read
  (%IW100..), holding registers written (%QW100..); 400 of each at most (MAX_MB_IO).
* Runtime v4's Modbus master plugin: its JSON (a list of devices with "config" and
  "io_points": fc, offset, iec_location, len, cycle_time_ms), as modbus_master_config_model.py
  reads it.
Every problem is a Problem (id, where, what): README.md lists the ids.
"""
from __future__ import annotations

import json
import re
from dataclasses import dataclass, field

# Protocol limits of one request (Modbus Application Protocol 1.1b3), as the blocks check them.
MAX_READ_BITS, MAX_WRITE_BITS, MAX_READ_REGS, MAX_WRITE_REGS = 2000, 1968, 125, 123
V3_MAX_IO = 400                 # modbus_master.cpp MAX_MB_IO: entries per area
V3_FIRST = 100                  # its first byte/word: %IX100.0, %IW100, %QX100.0, %QW100
READ_FCS, WRITE_FCS = (1, 2, 3, 4), (5, 6, 15, 16)
BIT_FCS = (1, 2, 5, 15)


class Problem(Exception):
    """One entry the blocks cannot serve as given: README.md's id, where, what."""

    def __init__(self, pid: str, where: str, what: str):
        super().__init__(f"{pid}: {where}: {what}")
        self.pid, self.where, self.what = pid, where, what


@dataclass
class Range:
    """One read (fc 1..4) or write (fc 5/6/15/16) of `count` bits or registers from `addr`,
    at the located addresses `located` (one per bit or register, e.g. '%IX100.0', '%IW100')."""
    fc: int
    addr: int
    count: int
    located: list
    period_ms: int
    where: str

    @property
    def bits(self) -> bool:
        return self.fc in BIT_FCS

    @property
    def words(self) -> int:
        """Snapshot words of a read (bits packed 16 to a word)."""
        return (self.count + 15) // 16 if self.bits else self.count


@dataclass
class Device:
    name: str
    port: str                   # the blocks' Port: a serial device, or tcp://host:port
    slave: int
    baud: int = 0               # serial only
    parity: str = ""
    data_bits: int = 0
    stop_bits: int = 0
    timeout_ms: int = 1000
    reads: list = field(default_factory=list)
    writes: list = field(default_factory=list)
    where: str = ""

    @property
    def serial(self) -> bool:
        return not self.port.startswith("tcp://")


def _int(text, where, what, pid="OI-02"):
    try:
        value = int(str(text).strip(), 10)
    except ValueError:
        raise Problem(pid, where, f"{what} {text!r} is not a number") from None
    return value


def check_range(r: Range, problems: list):
    """The one-request limits and the address space; a Problem each."""
    limit = {1: MAX_READ_BITS, 2: MAX_READ_BITS, 3: MAX_READ_REGS, 4: MAX_READ_REGS,
             5: 1, 6: 1, 15: MAX_WRITE_BITS, 16: MAX_WRITE_REGS}[r.fc]
    kind = "bits" if r.bits else "registers"
    if not 1 <= r.count <= limit:
        problems.append(Problem("OI-03", r.where, f"{r.count} {kind} for FC{r.fc:02d}: one "
                                f"request carries 1..{limit}"))
    if not 0 <= r.addr or r.addr + r.count > 0x10000:
        problems.append(Problem("OI-04", r.where, f"address {r.addr} + {r.count} {kind} is "
                                "outside 0..65535"))


def check_device(d: Device, problems: list):
    """Slave id and line settings the blocks take (docs/errors.md 200, 207)."""
    if not 1 <= d.slave <= 247:
        problems.append(Problem("OI-05", d.where, f"slave id {d.slave}: the blocks poll 1..247"))
    if d.serial:
        bad = []
        if d.baud <= 0 or d.baud > 4000000:
            bad.append(f"baud {d.baud}")
        if d.parity not in ("N", "E", "O"):
            bad.append(f"parity {d.parity!r}")
        if d.data_bits != 8:
            bad.append(f"{d.data_bits} data bits (RTU carries 8)")
        if d.stop_bits not in (1, 2):
            bad.append(f"{d.stop_bits} stop bits")
        if bad:
            problems.append(Problem("OI-06", d.where, "line settings the blocks cannot use: "
                                    + ", ".join(bad)))
    if not 0 < d.timeout_ms <= 60000:
        problems.append(Problem("OI-06", d.where, f"timeout {d.timeout_ms} ms: the blocks take "
                                "1..60000"))


# ----- OpenPLC v3: mbconfig.cfg -----
V3_LINE = re.compile(r'^\s*([A-Za-z_][\w.]*)\s*=\s*"(.*)"\s*$')


def read_v3(text: str, source: str, ignore_pause: bool = False) -> tuple[list, int, list]:
    """(devices, polling period ms, problems) of an mbconfig.cfg."""
    problems, top, devs = [], {}, {}
    for n, line in enumerate(text.splitlines(), 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        m = V3_LINE.match(line)
        if not m:
            problems.append(Problem("OI-02", f"{source}:{n}", f"not a 'key = \"value\"' line: "
                                    f"{line.strip()[:60]!r}"))
            continue
        key, value = m.groups()
        dm = re.match(r"^device(\d+)\.(\w+)$", key)
        if dm:
            devs.setdefault(int(dm.group(1)), {})[dm.group(2)] = (value, f"{source}:{n}")
        else:
            top[key] = (value, f"{source}:{n}")
    if "Num_Devices" not in top:
        raise Problem("OI-01", source, "no Num_Devices line: not an OpenPLC v3 mbconfig.cfg")
    num = _int(top["Num_Devices"][0], top["Num_Devices"][1], "Num_Devices")
    period = _int(top.get("Polling_Period", ("100", source))[0],
                  top.get("Polling_Period", ("", source))[1], "Polling_Period")
    timeout = _int(top.get("Timeout", ("1000", source))[0], top.get("Timeout", ("", source))[1],
                   "Timeout")
    if sorted(devs) != list(range(num)):
        problems.append(Problem("OI-02", source, f"Num_Devices is {num} but the devices are "
                                f"{sorted(devs) or 'none'}"))
    counters = {"IX": 0, "QX": 0, "IW": 0, "QW": 0}
    devices = []
    for i in sorted(devs):
        keys = devs[i]
        where = f"{source}: device{i}"

        def get(k, default=None, number=False):
            if k not in keys:
                if default is None:
                    problems.append(Problem("OI-02", where, f"device{i}.{k} is missing"))
                    return 0 if number else ""
                return default
            value, at = keys[k]
            return _int(value, at, f"device{i}.{k}") if number else value
        try:
            name = get("name")
            where = f"{source}: device{i} {name!r}"
            protocol = get("protocol")
            address = get("address")
            slave = get("slave_id", number=True)
            if protocol == "TCP":
                port = f"tcp://{address}:{get('IP_Port', number=True)}"
                dev = Device(name, port, slave, timeout_ms=timeout, where=where)
            elif protocol == "RTU":
                dev = Device(name, address, slave, get("RTU_Baud_Rate", number=True),
                             get("RTU_Parity")[:1], get("RTU_Data_Bits", number=True),
                             get("RTU_Stop_Bits", number=True), timeout, where=where)
                pause = get("RTU_TX_Pause", "0")
                pause = 0 if pause in ("", "None") else _int(pause, where, "RTU_TX_Pause")
                if pause and not ignore_pause:
                    problems.append(Problem("OI-07", where, f"RTU_TX_Pause {pause} ms: the "
                                            "blocks pace the line themselves (t3.5 between "
                                            "frames); --ignore-pause converts without it"))
            else:
                problems.append(Problem("OI-02", where, f"protocol {protocol!r} is neither "
                                        "RTU nor TCP"))
                continue
            # modbus_master.cpp's order per device: DI, coils, IR, HR read, HR write; its
            # buffers run on from device to device whatever a request returns.
            plan = (("Discrete_Inputs", 2, "IX"), ("Coils", 15, "QX"),
                    ("Input_Registers", 4, "IW"), ("Holding_Registers_Read", 3, "IW"),
                    ("Holding_Registers", 16, "QW"))
            for key, fc, area in plan:
                start = get(f"{key}_Start", number=True)
                size = get(f"{key}_Size", number=True)
                if size == 0:
                    continue
                first = counters[area]
                counters[area] += size
                rwhere = f"{where} {key} {start}+{size}"
                if counters[area] > V3_MAX_IO:
                    problems.append(Problem("OI-08", rwhere, f"past OpenPLC's last Slave Devices "
                                            f"{'bit' if area[1] == 'X' else 'word'} "
                                            f"({V3_MAX_IO} per area)"))
                    continue
                located = [v3_located(area, first + k) for k in range(size)]
                r = Range(fc, start, size, located, period, rwhere)
                check_range(r, problems)
                (dev.reads if fc in READ_FCS else dev.writes).append(r)
            check_device(dev, problems)
            devices.append(dev)
        except Problem as p:
            problems.append(p)
    return devices, period, problems


def v3_located(area: str, index: int) -> str:
    """The located address OpenPLC v3 gives Slave Devices entry `index` of an area."""
    if area[1] == "X":
        return f"%{area}{V3_FIRST + index // 8}.{index % 8}"
    return f"%{area}{V3_FIRST + index}"


# ----- Runtime v4: the Modbus master plugin's JSON -----
IEC_RE = re.compile(r"^%([IQM])([XBWDL])(\d+)(?:\.(\d+))?$", re.IGNORECASE)
V4_AREA = {1: ("I", "X"), 2: ("I", "X"), 3: ("I", "W"), 4: ("I", "W"),
           5: ("Q", "X"), 15: ("Q", "X"), 6: ("Q", "W"), 16: ("Q", "W")}


def read_v4(text: str, source: str) -> tuple[list, int, list]:
    """(devices, shortest cycle ms, problems) of the plugin's JSON."""
    try:
        data = json.loads(text)
    except json.JSONDecodeError as err:
        raise Problem("OI-01", source, f"not JSON ({err.msg}, line {err.lineno})") from None
    if not isinstance(data, list):
        raise Problem("OI-01", source, "not the Modbus master plugin's JSON (a list of devices)")
    problems, devices, cycles = [], [], []
    for i, entry in enumerate(data):
        where = f"{source}: device #{i + 1}"
        if not isinstance(entry, dict) or not isinstance(entry.get("config", {}), dict):
            problems.append(Problem("OI-02", where, "a device is an object with a 'config'"))
            continue
        name = str(entry.get("name", "UNDEFINED"))
        where = f"{source}: device #{i + 1} {name!r}"
        cfg = entry.get("config", {})
        if entry.get("protocol", "MODBUS") != "MODBUS":
            problems.append(Problem("OI-02", where, f"protocol {entry.get('protocol')!r}"))
            continue
        transport = cfg.get("transport", "tcp")

        def num(key, default):
            value = cfg.get(key, default)
            if isinstance(value, bool) or not isinstance(value, int):
                problems.append(Problem("OI-02", where, f"{key} {value!r} is not an integer"))
                return default
            return value
        slave, timeout = num("slave_id", 1), num("timeout_ms", 1000)
        if transport == "rtu":
            dev = Device(name, str(cfg.get("serial_port", "")), slave, num("baud_rate", 9600),
                         str(cfg.get("parity", "N")), num("data_bits", 8), num("stop_bits", 1),
                         timeout, where=where)
            if not dev.port:
                problems.append(Problem("OI-02", where, "serial_port is empty"))
        elif transport == "tcp":
            dev = Device(name, f"tcp://{cfg.get('host', '127.0.0.1')}:{num('port', 502)}",
                         slave, timeout_ms=timeout, where=where)
        else:
            problems.append(Problem("OI-02", where, f"transport {transport!r} is neither rtu "
                                    "nor tcp"))
            continue
        points = cfg.get("io_points", [])
        if not isinstance(points, list):
            problems.append(Problem("OI-02", where, "io_points is not a list"))
            points = []
        for k, point in enumerate(points):
            r = v4_point(point, f"{where} io_points[{k}]", problems)
            if r is not None:
                check_range(r, problems)
                (dev.reads if r.fc in READ_FCS else dev.writes).append(r)
                cycles.append(r.period_ms)
        check_device(dev, problems)
        devices.append(dev)
    return devices, min(cycles, default=1000), problems


def v4_point(point, where: str, problems: list) -> Range | None:
    if not isinstance(point, dict) or not {"fc", "offset", "iec_location", "len"} <= set(point):
        problems.append(Problem("OI-02", where, "an io_point has fc, offset, iec_location, len"))
        return None
    fc, length, cycle = point["fc"], point["len"], point.get("cycle_time_ms", 1000)
    if fc not in V4_AREA or isinstance(fc, bool):
        problems.append(Problem("OI-09", where, f"function code {fc!r}: the blocks serve "
                                "1, 2, 3, 4, 5, 6, 15, 16"))
        return None
    for key, value in (("len", length), ("cycle_time_ms", cycle)):
        if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
            problems.append(Problem("OI-02", where, f"{key} {value!r} is not a positive integer"))
            return None
    offset = str(point["offset"]).strip()
    try:                        # the plugin's parse_modbus_offset: decimal or 0x hex
        addr = int(offset, 16) if offset.lower().startswith("0x") else int(offset, 10)
    except ValueError:
        problems.append(Problem("OI-02", where, f"offset {point['offset']!r} is not a number"))
        return None
    m = IEC_RE.match(str(point["iec_location"]).strip())
    if not m:
        problems.append(Problem("OI-02", where, f"iec_location {point['iec_location']!r}"))
        return None
    area, size, byte, bit = m.group(1).upper(), m.group(2).upper(), int(m.group(3)), m.group(4)
    want = V4_AREA[fc]
    if (area, size) != want:
        problems.append(Problem("OI-08", where, f"FC{fc:02d} into {point['iec_location']}: the "
                                f"converted program fills %{want[0]}{want[1]} addresses only "
                                "(one bit per coil or input, one WORD per register)"))
        return None
    if fc in (5, 6) and length != 1:
        problems.append(Problem("OI-09", where, f"FC{fc:02d} with len {length}: the plugin "
                                "writes the first value only; use FC15/16 for more"))
        return None
    if size == "X":
        if bit is None or not 0 <= int(bit) <= 7:
            problems.append(Problem("OI-02", where, f"iec_location {point['iec_location']!r}"))
            return None
        first = byte * 8 + int(bit)
        located = [f"%{area}X{(first + k) // 8}.{(first + k) % 8}" for k in range(length)]
    else:
        located = [f"%{area}W{byte + k}" for k in range(length)]
    return Range(fc, addr, length, located, cycle, where)
