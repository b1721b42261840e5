"""Device adapters (serial IMU, CAN IMU, Modbus rotary table) and their virtual twins."""
