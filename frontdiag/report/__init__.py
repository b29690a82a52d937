"""frontdiag.report"""
