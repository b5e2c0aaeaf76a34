"""Reading a store for people: the paper's tables (:mod:`.aggregate`), estimators side by side
(:mod:`.compare`), the Markdown report (:mod:`.markdown`) and its plots, sweep plots."""
