"""Row layouts (numpy structured dtypes) of everything the bench derives, and their helpers."""
