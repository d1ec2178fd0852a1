"""Writes fixtures/*.cfg with OpenPLC v3's own generator: webserver.py's generate_mbconfig(),
taken from its source (ast), run on a scratch openplc.db holding the Slave_dev rows below as the
Slave Devices page stores them (its schema, its Settings). So the fixtures are what OpenPLC
writes, not our reading of it. Run: python mkfixture.py [OPENPLC_V3_DIR] (default
$OPENPLC_V3, else /opt/OpenPLC_v3, the toolchain's documented place); test_oplc_import.py
checks the committed fixtures against a fresh run when OpenPLC v3 is there."""
import ast
import os
import sqlite3
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
SCHEMA = """CREATE TABLE "Slave_dev" ("dev_id" INTEGER NOT NULL UNIQUE, "dev_name" TEXT NOT NULL
UNIQUE, "dev_type" TEXT NOT NULL, "slave_id" INTEGER NOT NULL, "com_port" TEXT, "baud_rate"
INTEGER, "parity" TEXT, "data_bits" INTEGER, "stop_bits" INTEGER, "ip_address" TEXT, "ip_port"
INTEGER, "di_start" INTEGER NOT NULL, "di_size" INTEGER NOT NULL, "coil_start" INTEGER NOT NULL,
"coil_size" INTEGER NOT NULL, "ir_start" INTEGER NOT NULL, "ir_size" INTEGER NOT NULL,
"hr_read_start" INTEGER NOT NULL, "hr_read_size" INTEGER NOT NULL, "hr_write_start" INTEGER NOT
NULL, "hr_write_size" INTEGER NOT NULL, "pause" INTEGER, PRIMARY KEY("dev_id" AUTOINCREMENT));
CREATE TABLE "Settings" ("Key" TEXT NOT NULL UNIQUE, "Value" TEXT NOT NULL,
PRIMARY KEY("Key"));"""
# (name, type, slave, port, baud, parity, data, stop, ip, ip_port,
#  di start/size, coil start/size, ir start/size, hr read start/size, hr write start/size, pause)
# as the page stores them: a TCP device keeps the RTU fields empty and the other way round.
RELAYS = ("relays", "RTU", 2, "/dev/ttyUSB0", 9600, "None", 8, 2, "", 0,
          0, 8, 0, 4, 0, 0, 0, 0, 0, 0, 0)
METER = ("meter", "RTU", 5, "/dev/ttyUSB0", 9600, "None", 8, 2, "", 0,
         0, 0, 0, 0, 0, 8, 20, 4, 10, 2, 0)
PLANTS = {
    "plant": [
        RELAYS,
        METER,
        ("esp io", "ESP32", 1, "", 0, "", 0, 0, "127.0.0.1", 5020,
         0, 8, 0, 8, 0, 1, 0, 0, 0, 1, 0),
        ("vfd", "TCP", 7, "", 0, "", 0, 0, "127.0.0.1", 5021,
         0, 0, 0, 0, 0, 0, 8192, 3, 8192, 2, 0),
    ],
    "line": [RELAYS, METER],   # test_oplc_line.py: the converted program against the simulator
    "com_port": [           # a Windows port name, as the page offers it: COM3 -> /dev/ttyS2
        ("uno", "Uno", 0 + 1, "COM3", 115200, "Even", 8, 1, "", 0,
         0, 5, 0, 4, 0, 6, 0, 0, 0, 3, 0),
    ],
    "bad": [                # what the blocks cannot serve as given
        ("big", "RTU", 1, "/dev/ttyUSB0", 9600, "None", 8, 1, "", 0,
         0, 0, 0, 0, 0, 130, 0, 0, 0, 0, 0),
        ("paused", "RTU", 2, "/dev/ttyUSB0", 9600, "None", 8, 1, "", 0,
         0, 1, 0, 0, 0, 0, 0, 0, 0, 0, 50),
        ("other line", "RTU", 3, "/dev/ttyUSB0", 19200, "None", 8, 1, "", 0,
         0, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0),
        ("broadcast", "TCP", 0, "", 0, "", 0, 0, "127.0.0.1", 502,
         0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 0),
    ],
}


def generator(openplc: str):
    """generate_mbconfig() of OpenPLC's webserver.py, with its own create_connection()."""
    path = os.path.join(openplc, "webserver", "webserver.py")
    with open(path, encoding="utf-8") as fh:
        tree = ast.parse(fh.read(), path)
    keep = [n for n in tree.body if isinstance(n, ast.FunctionDef)
            and n.name in ("generate_mbconfig", "create_connection")]
    assert len(keep) == 2, "webserver.py has no generate_mbconfig/create_connection"
    space = {"sqlite3": sqlite3, "Error": sqlite3.Error}
    exec(compile(ast.Module(body=keep, type_ignores=[]), path, "exec"), space)  # noqa: S102
    return space["generate_mbconfig"]


def make(openplc: str, plant: str, rows, polling="100", timeout="1000") -> str:
    """The mbconfig.cfg OpenPLC writes for these rows."""
    gen = generator(openplc)
    with tempfile.TemporaryDirectory() as tmp:
        db = sqlite3.connect(os.path.join(tmp, "openplc.db"))
        db.executescript(SCHEMA)
        db.executemany("INSERT INTO Settings VALUES (?, ?)",
                       [("Modbus_port", "502"), ("Slave_polling", polling),
                        ("Slave_timeout", timeout)])
        db.executemany("INSERT INTO Slave_dev (dev_name, dev_type, slave_id, com_port, baud_rate, "
                       "parity, data_bits, stop_bits, ip_address, ip_port, di_start, di_size, "
                       "coil_start, coil_size, ir_start, ir_size, hr_read_start, hr_read_size, "
                       "hr_write_start, hr_write_size, pause) VALUES "
                       f"({', '.join('?' * 21)})", rows)
        db.commit()
        db.close()
        cwd = os.getcwd()
        os.chdir(tmp)
        try:
            gen()
        finally:
            os.chdir(cwd)
        with open(os.path.join(tmp, "mbconfig.cfg"), encoding="utf-8") as fh:
            return fh.read()


def main():
    openplc = sys.argv[1] if len(sys.argv) > 1 else os.environ.get("OPENPLC_V3", "/opt/OpenPLC_v3")
    for plant, rows in PLANTS.items():
        with open(os.path.join(HERE, "fixtures", f"{plant}.cfg"), "w", encoding="utf-8") as fh:
            fh.write(make(openplc, plant, rows))


if __name__ == "__main__":
    main()
