"""selfsense.sensing"""
