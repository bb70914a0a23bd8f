"""selfsense.io"""
