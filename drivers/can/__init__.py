"""CAN driver: LTC-1 protocol codec, vendor adapters and the CAN driver process."""
