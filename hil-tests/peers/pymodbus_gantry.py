"""A third-party Modbus TCP server (pymodbus) holding the gantry's register map
(GANTRY_INTERFACE.md, crates/dbt-gantry/src/registers.rs), encoded here
independently from the Rust code, for the firmware client's interop test.

    python3 pymodbus_gantry.py PORT THICKNESS_MM [UNIT]          # Modbus TCP on 127.0.0.1:PORT
    python3 pymodbus_gantry.py /dev/PTY THICKNESS_MM [UNIT]      # Modbus RTU, 19200 8N1
"""
import sys

from pymodbus.datastore import ModbusDeviceContext, ModbusSequentialDataBlock, ModbusServerContext
from pymodbus import FramerType
from pymodbus.server import StartSerialServer, StartTcpServer


def registers(thickness_mm):
    return [
        1,                        # interface version
        3,                        # state: exposing
        round(thickness_mm * 10),  # 0.1 mm
        1234,                     # 123.4 N
        290,                      # 29.0 kV
        215,                      # 2.15 mAs per projection
        1,                        # W/Rh
        25,                       # projections
        (-240) & 0xFFFF,          # -24.0 deg, two's complement
        240,                      # 24.0 deg
        7,                        # current projection
        1 | (2 << 8),             # left, MLO
        0,                        # no fault
    ]


def main():
    where, thickness = sys.argv[1], float(sys.argv[2])
    unit = int(sys.argv[3]) if len(sys.argv) > 3 else 1
    # pymodbus data blocks are 1-based internally: address 0 is stored at index 1.
    block = ModbusSequentialDataBlock(1, registers(thickness))
    ctx = ModbusServerContext(devices={unit: ModbusDeviceContext(hr=block)}, single=False)
    if where.startswith("/"):
        StartSerialServer(context=ctx, port=where, baudrate=19200, bytesize=8, parity="N", stopbits=1,
                          framer=FramerType.RTU)
    else:
        StartTcpServer(context=ctx, address=("127.0.0.1", int(where)))


if __name__ == "__main__":
    main()
