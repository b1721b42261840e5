"""Virtual devices speaking the real wire protocols: serial IMU on a pty, CAN IMU on a virtual bus,
Modbus table, Modbus thermal chamber (TCP, or RTU on a pty pair)."""
