"""Report rendering: tables (md/csv/tex/html), leaderboard pages and figures."""
