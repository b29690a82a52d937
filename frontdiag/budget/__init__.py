"""frontdiag.budget"""
