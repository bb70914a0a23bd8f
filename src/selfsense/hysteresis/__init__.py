"""selfsense.hysteresis"""
