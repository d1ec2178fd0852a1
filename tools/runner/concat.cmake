# cmake -DOUT=file -DIN="a|b|c" -P concat.cmake : OUT = the files of IN, in order.
string(REPLACE "|" ";" IN "${IN}")
file(WRITE ${OUT} "")
foreach(f ${IN})
  file(READ ${f} text)
  file(APPEND ${OUT} "(* ---- ${f} ---- *)\n${text}\n")
endforeach()
