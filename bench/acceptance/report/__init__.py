"""What an acceptance run leaves in DIR: junit.xml, record.json, report.html and its PNGs.

junit.xml is for CI (one testcase per check; measured value and limits in its
system-out: junit.py); record.json is the review record (every measurement with limits,
units, verdict, timestamps, bench version, config and plan: record.py); report.html is for
people (html.py). Plots (plots.py) use matplotlib's Agg canvas through Figure objects, never
pyplot: no display, no global state. write.py writes them all.
"""
