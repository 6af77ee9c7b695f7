"""One run: its typed options (`runopts`) and its wiring (`runtime`: the plan, the stop signals, the ordered services)."""
