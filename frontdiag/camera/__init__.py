"""frontdiag.camera"""
