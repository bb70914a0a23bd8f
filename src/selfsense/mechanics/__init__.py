"""selfsense.mechanics"""
