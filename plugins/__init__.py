"""rfmitsuba plugins (installed as :mod:`rfmitsuba.plugins`)."""
