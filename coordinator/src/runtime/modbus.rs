//! The CMMO-ST Modbus TCP exchange thread (being written).
