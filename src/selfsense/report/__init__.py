"""selfsense.report"""
