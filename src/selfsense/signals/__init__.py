"""selfsense.signals"""
