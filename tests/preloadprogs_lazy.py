"""A dependency that ``preloadprogs.lazy`` imports only when it runs."""

WHAT = "lazy"
