"""``phyir bench``: the harness (measure, report) and every benchmark target."""
