"""selfsense.gap"""
