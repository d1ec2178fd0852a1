# cmake -DOUT=file -DIN="a|b|c" -P concat.cmake : OUT = the files of IN, in order, each after a
# comment with its name (no folder: the same sources give the same program in any checkout,
# which scripts/gencache.py needs to find iec2c's output of it).
string(REPLACE "|" ";" IN "${IN}")
file(WRITE ${OUT} "")
foreach(f ${IN})
  file(READ ${f} text)
  get_filename_component(name ${f} NAME)
  file(APPEND ${OUT} "(* ---- ${name} ---- *)\n${text}\n")
endforeach()
