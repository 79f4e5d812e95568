"""samii.closedloop"""
