"""The workflow's library side: studies, gathering fits, tables and figures."""
