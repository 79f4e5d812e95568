"""samii.sim"""
