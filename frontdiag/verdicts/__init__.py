"""frontdiag.verdicts"""
