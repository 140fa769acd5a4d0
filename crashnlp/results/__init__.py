"""The plain results and the files a run writes: Result, Response, the identified vehicle,
output folders, JSON and CSV files, figures. numpy only at import: no CasADi, no problem schema."""
