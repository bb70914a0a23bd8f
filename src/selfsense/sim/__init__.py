"""selfsense.sim"""
