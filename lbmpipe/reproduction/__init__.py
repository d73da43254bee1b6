"""The reproduction of Ku & Lin: the paper's pipe and cases, statistics, claims, figures, the
literate document, the accuracy-cost study and the stability suite. Built on the solver; nothing
below imports it."""
