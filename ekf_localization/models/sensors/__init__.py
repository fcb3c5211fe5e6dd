"""Measurement models: linear field selections, dead-wheel encoders (seed 000 eq. 29-33), camera.
"""
