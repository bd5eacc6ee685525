"""The command services above the run: solving recorded logs again (`resolve`: `bench solve LOG`, its outputs),
a thermal run's re-solve (`thermal`), the method comparison (`compare`: `bench solve --compare`) and an archive
of logs solved in parallel (`archive`: `bench solve --archive`)."""
